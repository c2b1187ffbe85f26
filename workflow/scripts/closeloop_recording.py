"""Snakemake script: close the loop on one recording of a real rig (thin wrapper around
ssamb.closeloop.run_closeloop)."""
from pathlib import Path

from ssamb.closeloop import run_closeloop
from ssamb.stages import job_log

with job_log(snakemake.log[0], "closeloop_recording"):  # noqa: F821
    run_closeloop(snakemake.input.data, Path(snakemake.output.json).parent,  # noqa: F821
                  config=snakemake.params.cfg, device=snakemake.params.device, progress=True,  # noqa: F821
                  workers=snakemake.threads, force=True)  # noqa: F821  (the outputs are Snakemake's)
