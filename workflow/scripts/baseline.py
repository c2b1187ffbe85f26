"""Snakemake script: ISO 14839-3 baseline (ssamb.robustness_stage.run_baseline)."""
import sys
from pathlib import Path

from ssamb.robustness_stage import run_baseline

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    inp = snakemake.input  # noqa: F821
    models = {Path(p).stem: p for p in inp.models}
    run_baseline(inp.closed_loop, models, snakemake.params.pid, snakemake.params.mu, snakemake.output.json)  # noqa: F821
