# The assumption study (config `study`): every open modelling choice varied one at a time over its
# plausible values, and the strongest in pairs. Each variant is a run (results/runs/study-*/) of
# the same rules, so each of its stages is its own job; stages whose inputs a variant does not
# change are shared (ssamb.scenarios.Plan). Target: `snakemake --cores 2 study`. Once the noise
# ensembles have run, the study reads their spread as the noise band of each headline.
import os


def study_inputs(wc):
    files = {"summaries": [f"results/{r}summary.json" for r in STUDY_RUNS]}
    if os.path.exists("results/ensemble/ensemble.json"):  # the noise band, once the ensembles ran
        files["ensemble"] = "results/ensemble/ensemble.json"
    return files


rule study_collect:
    """Gather the variants' headline numbers: results/study/study.json, tornado charts, table."""
    input:
        unpack(study_inputs),
    output:
        json="results/study/study.json",
        fig="results/study/tornado.png",
    params:
        study=config.get("study", {}),
        runs=STUDY_RUNS,
    log:
        "results/study/logs/collect.log",
    benchmark:
        "results/study/benchmarks/collect.tsv"
    script:
        "../scripts/study.py"


rule study:
    """The assumption study and the report that holds it (results/study/report.html)."""
    input:
        "results/study/study.json",
        "results/study/report.html",
