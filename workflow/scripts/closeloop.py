"""Snakemake script: close the loop with one measured data set (thin wrapper around
ssamb.closeloop.run_closeloop)."""
import sys
from pathlib import Path

from ssamb.closeloop import run_closeloop
from ssamb.config import validate_config

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = log
    cfg = snakemake.params.cfg  # noqa: F821
    validate_config(cfg)
    run_closeloop(snakemake.input.data, Path(snakemake.output.json).parent, config=cfg, progress=True,  # noqa: F821
                  workers=snakemake.threads)  # noqa: F821
