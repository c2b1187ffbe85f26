"""Snakemake script: ISO 14839-3 baseline (ssamb.stages.baseline.run_baseline); a failure in a scenario or study run is
recorded in its outputs (ssamb.stages.run_guarded)."""
from pathlib import Path

from ssamb.stages import job_log, run_guarded
from ssamb.stages.baseline import run_baseline

with job_log(snakemake.log[0], "baseline"):  # noqa: F821
    inp, out, wc, par = snakemake.input, snakemake.output, snakemake.wildcards, snakemake.params  # noqa: F821
    models = {Path(p).stem: p for p in inp.models}
    run_guarded("baseline", out, run_baseline, models, par.pid, par.mu, out.json, tolerate=bool(wc.run))
