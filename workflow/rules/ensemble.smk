# Noise ensembles (config `ensemble`): every chain of ensemble.runs (the default run and named
# scenarios) repeated over K noise realisations, each a run results/runs/<chain>.r<k>/ of the same
# rules (so each stage of each realisation is its own job; stages that do not depend on the seed
# are shared, ssamb.scenarios.Plan), and the ceilings: the default run's Fig. 4 and validation
# experiments repeated with only the converter noise drawn anew (results/runs/ceiling.r<k>/).
# Target: `snakemake --cores 2 ensemble` -> results/ensemble/ensemble.json and
# results/ensemble/report.html; results/summary.json and results/report.html hold the ensemble
# once ensemble.json exists (the next `snakemake --cores 2`), as they hold the study.
from ssamb.stages.ensemble import ceiling_channels

#: ceiling kind -> the default run's experiment it repeats
CEILING_EXPERIMENTS = {"fig4": config["assembly"]["fig4"], "validation": config["identification"]["validation"]}


rule ceiling:
    """Fit of each repeated nonlinear run against the others (the fit no model can exceed)."""
    input:
        records=lambda wc: [sim_file(r, CEILING_EXPERIMENTS[wc.kind]) for r in ["", *CEILING_RUNS]],
    output:
        json="results/ceiling/{kind}.json",
    params:
        channels=lambda wc: ceiling_channels(wc.kind),
    log:
        "results/logs/ceiling/{kind}.log",
    benchmark:
        "results/benchmarks/ceiling/{kind}.tsv"
    wildcard_constraints:
        kind="fig4|validation",
    script:
        "../scripts/ceiling.py"


rule ensemble_collect:
    """Per chain and headline: median and range over the realisations, the ceilings, the
    stability and delevitation fractions, which chain reproduces which of the paper's headlines."""
    input:
        summaries=[summary for runs in ENSEMBLE_RUNS.values() for _, summary in runs],
        fig4="results/ceiling/fig4.json",
        validation="results/ceiling/validation.json",
    output:
        json="results/ensemble/ensemble.json",
        fig="results/ensemble/ensemble.png",
    params:
        chains=ENSEMBLE_RUNS,
        criteria=(config.get("ensemble") or {}).get("criteria"),
    log:
        "results/ensemble/logs/collect.log",
    benchmark:
        "results/ensemble/benchmarks/collect.tsv"
    script:
        "../scripts/ensemble.py"


rule ensemble:
    """The noise ensembles and the report that holds them (results/ensemble/report.html)."""
    input:
        "results/ensemble/ensemble.json",
        "results/ensemble/report.html",
