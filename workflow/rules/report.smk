# summary.json per run (the paper-versus-reproduction numbers) and the HTML report.
import os


def needed_weights(run):
    """Subsystems whose weight a run's summary needs: those of its mu cases and the validation's."""
    cfg = RUN_CONFIGS[run]
    subs = {s for c in cfg["mu"]["cases"] for s in (SUBSYSTEMS if c == "all" else (c,))}
    return [s for s in SUBSYSTEMS if s in subs or s == cfg["validation"]["weight"]]


def run_experiments(run):
    """Experiments whose simulation meta a run's summary lists (all of them for the default run)."""
    cfg = RUN_CONFIGS[run]
    if not run:
        return list(cfg["experiments"])
    keys = ("identification.estimation", "identification.validation", "assembly.fig4", "uncertainty.experiment")
    names = [cfg[k.split(".")[0]][k.split(".")[1]] for k in keys] + ["sweep"]
    return list(dict.fromkeys(names))


def summary_inputs(wc):
    run = wc.run
    files = {
        "assemble": out("assemble", run, "model/assemble.json"),
        "evidence": [out("identify", run, f"ident/{s}_evidence.json", subsystem=s) for s in SUBSYSTEMS],
        "uncertainty": [out("uncertainty", run, f"uncertainty/{s}.json", subsystem=s) for s in needed_weights(run)],
        "mu": [out("mu", run, f"mu/{c}.json", case=c) for c in mu_cases(run)],
        "baseline": out("baseline", run, "mu/baseline.json"),
        "validation": out("validate", run, "validation/sweep.json"),
        "sims": [sim_file(run, e).replace(".npz", ".json") for e in run_experiments(run)],
    }
    if RUN_CONFIGS[run]["identification"].get("selection", "subsystem") == "loop":
        files["selection"] = out("select", run, "select/select.json")
    if not run:
        files["closeloop"] = expand("results/closeloop/{dataset}/closeloop.json", dataset=CLOSELOOP_DATASETS)
        if "runs/paper/" in SCENARIO_RUNS:
            files["paper"] = "results/runs/paper/summary.json"
        if os.path.exists("results/study/study.json"):  # optional: after `snakemake study`
            files["study"] = "results/study/study.json"
        if CEILING_RUNS:  # the cheap part of the ensembles: the ceiling of the Fig. 4 fits
            files["ceiling"] = "results/ceiling/fig4.json"
        if os.path.exists("results/ensemble/ensemble.json"):  # optional: after `snakemake ensemble`
            files["ensemble"] = "results/ensemble/ensemble.json"
    return files


rule summary:
    """Collect every stage's numbers of one run into its summary.json."""
    input:
        unpack(summary_inputs),
    output:
        "results/{run}summary.json",
    params:
        default_dataset=lambda wc: CLOSELOOP_DEFAULT if not wc.run else None,
    log:
        "results/{run}logs/summary.log",
    benchmark:
        "results/{run}benchmarks/summary.tsv"
    script:
        "../scripts/summary.py"


def report_inputs(wc):
    files = {"summary": "results/summary.json", "config_file": workflow.configfiles[0] if workflow.configfiles else "config.yaml",
             "figures": [f"results/{p}" for p in REPORT_FIGURES],
             "rigs": expand("results/rigs/{rig}/closeloop.json", rig=CLOSELOOP_RIGS)}
    # results/<which>report.html holds the study or the ensemble; every report holds them once they ran
    if wc.which == "study/" or os.path.exists("results/study/study.json"):
        files["study"] = "results/study/study.json"
    if wc.which == "ensemble/" or os.path.exists("results/ensemble/ensemble.json"):
        files["ensemble"] = "results/ensemble/ensemble.json"
    return files


#: stage figures the report shows (default run)
REPORT_FIGURES = (["model/fig4.png", "validation/fig9.png", "sim/levitate.npz"]
                  + [f"uncertainty/{s}_fig7.png" for s in SUBSYSTEMS]
                  + [f"mu/{c}_fig8.png" for c in config["mu"]["cases"]]
                  + [f"ident/{s}_{k}.png" for s in SUBSYSTEMS for k in ("orders", "validation")]
                  + [f"sim/{config['uncertainty']['experiment']}.npz"])


rule report:
    """Build the notebook from results/, execute it and render the HTML report (nbconvert);
    results/study/report.html also holds the assumption study, results/ensemble/report.html the
    noise ensembles."""
    input:
        unpack(report_inputs),
    output:
        html="results/{which}report.html",
        notebook="results/{which}report.ipynb",
    params:
        closeloop_dir=(f"results/closeloop/{CLOSELOOP_DEFAULT}" if CLOSELOOP_DEFAULT else None),
    log:
        "results/{which}logs/report.log",
    benchmark:
        "results/{which}benchmarks/report.tsv"
    wildcard_constraints:
        which="(study/|ensemble/)?",
    resources:
        mem_mb=3000,
        runtime=15,
    script:
        "../scripts/report.py"
