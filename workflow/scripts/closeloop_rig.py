"""Snakemake script: a real rig's recordings combined and judged on its held-out ones (thin
wrapper around ssamb.closeloop.recordings.run_recordings)."""
from pathlib import Path

from ssamb.closeloop.recordings import run_recordings
from ssamb.stages import job_log

with job_log(snakemake.log[0], "closeloop_rig"):  # noqa: F821
    p = snakemake.params  # noqa: F821
    reports = dict(zip(p.fit, snakemake.input.reports))  # noqa: F821
    fit = dict(zip(p.fit, snakemake.input.fit))  # noqa: F821
    hold = dict(zip(p.hold, snakemake.input.hold))  # noqa: F821
    run_recordings(fit, hold, Path(snakemake.output.json).parent,  # noqa: F821
                   config=p.cfg, device=p.device, progress=True, workers=snakemake.threads,  # noqa: F821
                   reports=reports, force=True)  # the outputs are Snakemake's
