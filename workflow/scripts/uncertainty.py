"""Snakemake script: uncertainty weight of one subsystem (ssamb.stages.uncertainty.run_uncertainty);
a failure in a scenario or study run is recorded in its outputs (ssamb.stages.run_guarded)."""

from ssamb.stages import job_log, run_guarded
from ssamb.stages.uncertainty import run_uncertainty

with job_log(snakemake.log[0], "uncertainty"):  # noqa: F821
    inp, out, wc, par = snakemake.input, snakemake.output, snakemake.wildcards, snakemake.params  # noqa: F821
    run_guarded("uncertainty", out, run_uncertainty, inp.multisine, inp.closed_loop, inp.selfsensing, wc.subsystem,
                par.uncertainty, out.weight, out.json, out.fig, tolerate=bool(wc.run))
