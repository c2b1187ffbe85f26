"""Snakemake script: ISO 14839-3 baseline (ssamb.stages.baseline.run_baseline)."""
import sys
from pathlib import Path

from ssamb.stages.baseline import run_baseline

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    models = {Path(p).stem: p for p in snakemake.input.models}  # noqa: F821
    run_baseline(models, snakemake.params.pid, snakemake.params.mu, snakemake.output.json)  # noqa: F821
