"""Snakemake script: simulate one experiment (thin wrapper around ssamb.sim.simulate)."""
import sys

from ssamb.config import validate_config
from ssamb.sim import simulate

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = log
    cfg = snakemake.params.cfg  # noqa: F821
    validate_config(cfg)
    result = simulate(cfg, snakemake.wildcards.experiment, progress=True)  # noqa: F821
    result.save(snakemake.output.npz)  # noqa: F821
