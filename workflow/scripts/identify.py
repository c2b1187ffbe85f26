"""Snakemake script: identify one subsystem (ssamb.identification_stage.run_identify)."""
import os
import sys
from pathlib import Path

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # reproducible (ill-conditioned amplifier) and faster in parallel

from ssamb.identification_stage import run_identify  # noqa: E402

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    out = snakemake.output  # noqa: F821
    run_identify(snakemake.input.est, snakemake.input.val, snakemake.wildcards.subsystem,  # noqa: F821
                 snakemake.params.identification, out.model, out.evidence,  # noqa: F821
                 out_variant=out.paper_variant, fig_dir=Path(out.fig_orders).parent)
