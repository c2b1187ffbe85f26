"""Snakemake script: the models selected by the assembled loop (ssamb.stages.select.run_select); a
failure in a scenario or study run is recorded in its outputs (ssamb.stages.run_guarded)."""
from pathlib import Path

from ssamb.stages import job_log, run_guarded
from ssamb.stages.select import run_select

with job_log(snakemake.log[0], "select"):  # noqa: F821
    inp, out, wc, par = snakemake.input, snakemake.output, snakemake.wildcards, snakemake.params  # noqa: F821
    cands = {Path(p).stem.replace("_candidates", ""): p for p in inp.candidates}
    models = {Path(p).stem: p for p in out.models}
    run_guarded("select", out, run_select, cands, inp.val, par.pid, models, out.json, tolerate=bool(wc.run))
