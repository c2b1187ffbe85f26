"""Snakemake script: gather the assumption study (ssamb.stages.study.collect_study)."""

from ssamb.stages.study import collect_study
from ssamb.stages import job_log

with job_log(snakemake.log[0], "study"):  # noqa: F821
    collect_study(snakemake.params.study, snakemake.params.runs, list(snakemake.input.summaries),  # noqa: F821
                  snakemake.output.json, snakemake.output.fig,  # noqa: F821
                  ensemble_json=snakemake.input.get("ensemble"))  # noqa: F821
