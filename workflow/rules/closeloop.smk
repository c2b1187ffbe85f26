# Close the loop with measured data: every data set named in config closeloop.datasets is
# replayed through the nominal model of the default run, its residual analysed, and the library
# effects that explain it fitted (ssamb.closeloop.run_closeloop). The physics sections and the
# analysis settings reach the job through params, so a changed value reruns exactly these jobs.
CLOSELOOP = config.get("closeloop", {})
CLOSELOOP_DATASETS = list(CLOSELOOP.get("datasets", {}))
CLOSELOOP_DEFAULT = CLOSELOOP.get("default_dataset")
if CLOSELOOP_DEFAULT is not None and CLOSELOOP_DEFAULT not in CLOSELOOP_DATASETS:
    raise WorkflowError(f"config.yaml: closeloop.default_dataset '{CLOSELOOP_DEFAULT}' is not in closeloop.datasets")
#: figures every analysis writes (sensor_ratio.png too when an axis is excited)
CLOSELOOP_FIGURES = ["calibration.png", "features.png", "residual_time.png", "residual_spectra.png", "evidence.png"]


def closeloop_config(wildcards):
    """Physics of the nominal model plus the analysis settings (not the data set list)."""
    cfg = _sim_config(config)
    cfg["closeloop"] = {k: v for k, v in CLOSELOOP.items() if k not in ("datasets", "default_dataset")}
    return cfg


rule closeloop:
    """Replay, residual, signatures, fit and report for one measured data set."""
    input:
        data=lambda wc: CLOSELOOP["datasets"][wc.dataset],
    output:
        json="results/closeloop/{dataset}/closeloop.json",
        figures=expand("results/closeloop/{{dataset}}/{fig}", fig=CLOSELOOP_FIGURES),
    params:
        cfg=closeloop_config,
    log:
        "results/logs/closeloop/{dataset}.log",
    benchmark:
        "results/benchmarks/closeloop/{dataset}.tsv"
    wildcard_constraints:
        dataset="[A-Za-z0-9_]+",
    threads: 2  # independent replays on two processes (the result does not depend on it)
    resources:
        mem_mb=3000,
        runtime=30,
    script:
        "../scripts/closeloop.py"
