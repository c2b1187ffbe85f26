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
    cfg["closeloop"] = {k: v for k, v in CLOSELOOP.items() if k not in ("datasets", "default_dataset", "rigs")}
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


# Real rigs of other devices (config closeloop.rigs): each fitting recording is analysed on its
# own (rule closeloop_recording), then the calibrated parameters are combined and judged on the
# held-out recordings (rule closeloop_rig; ssamb.closeloop.recordings). The device's own
# configuration reaches the jobs through params.
CLOSELOOP_RIGS = CLOSELOOP.get("rigs", {}) or {}


def rig_device_config(wc):
    """The configuration of a rig's device model (its own file, or the one the rig names)."""
    from ssamb.device import get_device

    spec = CLOSELOOP_RIGS[wc.rig]
    return canonical(get_device(spec["device"]).load_config(spec.get("config")))


rule closeloop_recording:
    """Close the loop on one fitting recording of a real rig (its own fitting and held-out parts)."""
    input:
        data=lambda wc: CLOSELOOP_RIGS[wc.rig]["fit"][wc.recording],
    output:
        json="results/rigs/recordings/{rig}/{recording}/closeloop.json",
    params:
        cfg=rig_device_config,
        device=lambda wc: CLOSELOOP_RIGS[wc.rig]["device"],
    log:
        "results/logs/rigs/{rig}/{recording}.log",
    benchmark:
        "results/benchmarks/rigs/{rig}/{recording}.tsv"
    wildcard_constraints:
        rig="[A-Za-z0-9_]+",
        recording="[A-Za-z0-9_]+",
    # One process: a recording's analysis is short (about 20 CPU s) and gains little from a second
    # one; on two cores it then runs beside the AMB chain's one-process stages instead of after them.
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    script:
        "../scripts/closeloop_recording.py"


rule closeloop_rig:
    """Combine a rig's fitting recordings and judge the result on its held-out recordings."""
    input:
        reports=lambda wc: [f"results/rigs/recordings/{wc.rig}/{r}/closeloop.json" for r in CLOSELOOP_RIGS[wc.rig]["fit"]],
        fit=lambda wc: list(CLOSELOOP_RIGS[wc.rig]["fit"].values()),
        hold=lambda wc: list(CLOSELOOP_RIGS[wc.rig]["hold"].values()),
    output:
        json="results/rigs/{rig}/closeloop.json",
    params:
        cfg=rig_device_config,
        device=lambda wc: CLOSELOOP_RIGS[wc.rig]["device"],
        fit=lambda wc: list(CLOSELOOP_RIGS[wc.rig]["fit"]),
        hold=lambda wc: list(CLOSELOOP_RIGS[wc.rig]["hold"]),
    log:
        "results/logs/rigs/{rig}.log",
    benchmark:
        "results/benchmarks/rigs/{rig}.tsv"
    wildcard_constraints:
        rig="[A-Za-z0-9_]+",
    threads: 1  # as closeloop_recording
    resources:
        mem_mb=2000,
        runtime=30,
    script:
        "../scripts/closeloop_rig.py"
