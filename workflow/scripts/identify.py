"""Snakemake script: identify one subsystem (ssamb.stages.identify.run_identify);
a failure in a scenario or study run is recorded in its outputs (ssamb.stages.run_guarded)."""
from pathlib import Path

from ssamb.stages import job_log, run_guarded
from ssamb.stages.identify import run_identify

with job_log(snakemake.log[0], "identify"):  # noqa: F821
    inp, out, wc, par = snakemake.input, snakemake.output, snakemake.wildcards, snakemake.params  # noqa: F821
    run_guarded("identify", out, run_identify, inp.est, inp.val, wc.subsystem, par.identification, out.model,
                out.evidence, out_variant=out.paper_variant, fig_dir=Path(out.fig_orders).parent,
                out_candidates=out.candidates, tolerate=bool(wc.run))
