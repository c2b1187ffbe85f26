"""Snakemake script: results/report.html (ssamb.report.build_report)."""
from pathlib import Path

from ssamb.report import build_report
from ssamb.stages import job_log

with job_log(snakemake.log[0], "report"):  # noqa: F821
    inp = snakemake.input  # noqa: F821
    build_report(Path(inp.summary).parent, snakemake.output.html, out_ipynb=snakemake.output.notebook,  # noqa: F821
                 config_path=inp.config_file, closeloop_dir=snakemake.params.closeloop_dir,  # noqa: F821
                 study_json=inp.get("study"), ensemble_json=inp.get("ensemble"))
