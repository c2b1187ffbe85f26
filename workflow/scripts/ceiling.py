"""Snakemake script: the ceiling of the fits over repeated runs (ssamb.stages.ensemble.run_ceiling)."""

from ssamb.stages import job_log
from ssamb.stages.ensemble import run_ceiling

with job_log(snakemake.log[0], "ceiling"):  # noqa: F821
    run_ceiling(list(snakemake.input.records), snakemake.params.channels, snakemake.output.json)  # noqa: F821
