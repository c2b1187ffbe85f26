"""Snakemake script: sweep validation (ssamb.stages.validate.run_validate)."""
import sys
from pathlib import Path

from ssamb.stages.validate import run_validate

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    inp, out = snakemake.input, snakemake.output  # noqa: F821
    models = {Path(p).stem: p for p in inp.models}
    run_validate(inp.sweep, models, inp.weight, snakemake.params.sim, snakemake.params.validation,  # noqa: F821
                 out.json, out.fig)
