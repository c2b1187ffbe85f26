"""Snakemake script: gather the noise ensembles (ssamb.stages.ensemble.collect_ensemble)."""

from ssamb.stages import job_log
from ssamb.stages.ensemble import collect_ensemble

with job_log(snakemake.log[0], "ensemble"):  # noqa: F821
    inp, par = snakemake.input, snakemake.params  # noqa: F821
    collect_ensemble(par.chains, {"fig4": inp.fig4, "validation": inp.validation}, par.criteria,
                     snakemake.output.json, snakemake.output.fig)  # noqa: F821
