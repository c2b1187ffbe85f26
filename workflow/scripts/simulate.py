"""Snakemake script: simulate one experiment (ssamb.stages.simulate.run_simulate);
a failure in a scenario or study run is recorded in its outputs (ssamb.stages.run_guarded)."""

from ssamb.stages import job_log, run_guarded
from ssamb.stages.simulate import run_simulate

with job_log(snakemake.log[0], "simulate"):  # noqa: F821
    inp, out, wc, par = snakemake.input, snakemake.output, snakemake.wildcards, snakemake.params  # noqa: F821
    run_guarded("simulate", out, run_simulate, par.cfg, wc.experiment, out.npz, progress=True, tolerate=bool(wc.run))
