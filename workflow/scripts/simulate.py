"""Snakemake script: simulate one experiment (ssamb.stages.simulate.run_simulate)."""
import sys

from ssamb.stages.simulate import run_simulate

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = log
    run_simulate(snakemake.params.cfg, snakemake.wildcards.experiment, snakemake.output.npz, progress=True)  # noqa: F821
