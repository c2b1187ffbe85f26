"""Snakemake script: the ceiling of the fits over repeated runs (ssamb.stages.ensemble.run_ceiling)."""
import sys

from ssamb.stages.ensemble import run_ceiling

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    run_ceiling(list(snakemake.input.records), snakemake.params.channels, snakemake.output.json)  # noqa: F821
