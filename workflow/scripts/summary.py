"""Snakemake script: a run's summary.json (ssamb.stages.summary.write_summary)."""
from pathlib import Path

from ssamb.stages.summary import write_summary
from ssamb.stages import job_log

with job_log(snakemake.log[0], "summary"):  # noqa: F821
    inp = snakemake.input  # noqa: F821
    cl = {Path(p).parent.name: p for p in inp.get("closeloop", [])}
    write_summary(
        snakemake.output[0],  # noqa: F821
        assemble_json=inp.assemble,
        evidence_jsons={Path(p).stem.replace("_evidence", ""): p for p in inp.evidence},
        uncertainty_jsons={Path(p).stem: p for p in inp.uncertainty},
        mu_jsons={Path(p).stem: p for p in inp.mu},
        baseline_json=inp.baseline,
        validation_json=inp.validation,
        closeloop_json=cl.get(snakemake.params.default_dataset),  # noqa: F821
        closeloop_all=cl,
        sim_metas=list(inp.sims),
        paper_json=inp.get("paper"),
        study_json=inp.get("study"),
        ceiling_json=inp.get("ceiling"),
        ensemble_json=inp.get("ensemble"),
        selection_json=inp.get("selection"),
    )
