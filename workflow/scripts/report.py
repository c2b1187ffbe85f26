"""Snakemake script: results/report.html (ssamb.report.build_report)."""
import sys
from pathlib import Path

from ssamb.report import build_report

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    build_report(Path(snakemake.input.summary).parent, snakemake.output.html,  # noqa: F821
                 out_ipynb=snakemake.output.notebook, config_path=snakemake.input.config_file,  # noqa: F821
                 closeloop_dir=snakemake.params.closeloop_dir)  # noqa: F821
