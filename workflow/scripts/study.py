"""Snakemake script: gather the assumption study (ssamb.stages.study.collect_study)."""
import sys

from ssamb.stages.study import collect_study

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    collect_study(snakemake.params.study, snakemake.params.runs, list(snakemake.input.summaries),  # noqa: F821
                  snakemake.output.json, snakemake.output.fig)  # noqa: F821
