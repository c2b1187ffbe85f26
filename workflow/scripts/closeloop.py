"""Snakemake script: close the loop with one measured data set (thin wrapper around
ssamb.closeloop.run_closeloop)."""
from pathlib import Path

from ssamb.closeloop import run_closeloop
from ssamb.config import validate_config
from ssamb.stages import job_log

with job_log(snakemake.log[0], "closeloop"):  # noqa: F821
    cfg = snakemake.params.cfg  # noqa: F821
    validate_config(cfg)
    run_closeloop(snakemake.input.data, Path(snakemake.output.json).parent, config=cfg, progress=True,  # noqa: F821
                  workers=snakemake.threads, force=True)  # noqa: F821  (the outputs are Snakemake's)
