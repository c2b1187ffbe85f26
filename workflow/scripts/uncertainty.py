"""Snakemake script: uncertainty weight of one subsystem (ssamb.robustness_stage.run_uncertainty)."""
import sys

from ssamb.robustness_stage import run_uncertainty

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    inp, out = snakemake.input, snakemake.output  # noqa: F821
    run_uncertainty(inp.multisine, inp.closed_loop, inp.selfsensing, snakemake.wildcards.subsystem,  # noqa: F821
                    snakemake.params.uncertainty, out.weight, out.json, out.fig)  # noqa: F821
