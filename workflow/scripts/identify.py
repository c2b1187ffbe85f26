"""Snakemake script: identify one subsystem (ssamb.stages.identify.run_identify)."""
import sys
from pathlib import Path

from ssamb.stages.identify import run_identify

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    out = snakemake.output  # noqa: F821
    run_identify(snakemake.input.est, snakemake.input.val, snakemake.wildcards.subsystem,  # noqa: F821
                 snakemake.params.identification, out.model, out.evidence,  # noqa: F821
                 out_variant=out.paper_variant, fig_dir=Path(out.fig_orders).parent)
