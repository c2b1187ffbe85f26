"""Snakemake script: one parameter-study point (ssamb.stages.study.run_study_point)."""
import os
import sys

os.environ["OPENBLAS_NUM_THREADS"] = "1"

from ssamb.stages.study import run_study_point  # noqa: E402

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    run_study_point(snakemake.params.cfg, snakemake.params.parameter,  # noqa: F821
                    float(snakemake.wildcards.value), snakemake.output[0])  # noqa: F821
