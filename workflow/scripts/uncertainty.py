"""Snakemake script: uncertainty weight of one subsystem (ssamb.stages.uncertainty.run_uncertainty)."""
import sys

from ssamb.stages.uncertainty import run_uncertainty

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    inp, out = snakemake.input, snakemake.output  # noqa: F821
    run_uncertainty(inp.multisine, inp.closed_loop, inp.selfsensing, snakemake.wildcards.subsystem,  # noqa: F821
                    snakemake.params.uncertainty, out.weight, out.json, out.fig)  # noqa: F821
