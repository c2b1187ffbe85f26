"""Snakemake script: sweep validation (ssamb.stages.validate.run_validate); a failure in a scenario or study run is
recorded in its outputs (ssamb.stages.run_guarded)."""
from pathlib import Path

from ssamb.stages import job_log, run_guarded
from ssamb.stages.validate import run_validate

with job_log(snakemake.log[0], "validate"):  # noqa: F821
    inp, out, wc, par = snakemake.input, snakemake.output, snakemake.wildcards, snakemake.params  # noqa: F821
    models = {Path(p).stem: p for p in inp.models}
    run_guarded("validate", out, run_validate, inp.sweep, models, inp.weight, par.sim, par.validation, out.json,
                out.fig, tolerate=bool(wc.run))
