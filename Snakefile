# ssamb: reproducible mu-analysis of a self-sensing AMB (see README.md).
#
#   snakemake --cores 2                       full reproduction -> results/report.html
#   snakemake --cores 2 study                 the assumption study -> results/study/report.html
#   snakemake --cores 2 ensemble              the noise ensembles -> results/ensemble/report.html
#   snakemake --cores 2 results/mu/selfsensing.json      one stage (and what it needs)
#
# Every config value reaches its rules through `params:`, so a changed value reruns exactly the
# rules that use it and their descendants (Snakemake's default rerun triggers include params).
# Runs: the default run writes to results/, the named scenarios of config `scenarios` (the
# paper's way: results/runs/paper/), the study variants and the noise realisations
# (<chain>.r<k>) to results/runs/<name>/.

configfile: "config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/closeloop.smk"
include: "workflow/rules/analysis.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/study.smk"
include: "workflow/rules/ensemble.smk"


rule all:
    default_target: True
    input:
        "results/report.html",
        "results/summary.json",
        [f"results/{r}summary.json" for r in SCENARIO_RUNS],
        expand("results/sim/{experiment}.npz", experiment=SIM_EXPERIMENTS),
        expand("results/closeloop/{dataset}/closeloop.json", dataset=CLOSELOOP_DATASETS),
        expand("results/rigs/{rig}/closeloop.json", rig=CLOSELOOP_RIGS),
