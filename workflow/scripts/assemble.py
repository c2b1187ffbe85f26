"""Snakemake script: closed-loop LTI assembly and Fig. 4 (ssamb.stages.assemble.run_assemble);
a failure in a scenario or study run is recorded in its outputs (ssamb.stages.run_guarded)."""
from pathlib import Path

from ssamb.stages import job_log, run_guarded
from ssamb.stages.assemble import run_assemble

with job_log(snakemake.log[0], "assemble"):  # noqa: F821
    inp, out, wc, par = snakemake.input, snakemake.output, snakemake.wildcards, snakemake.params  # noqa: F821
    models = {Path(p).stem: p for p in inp.models}
    paper = {Path(p).stem.replace("_paper", ""): p for p in inp.paper}
    run_guarded("assemble", out, run_assemble, models, paper, inp.fig4, par.pid, out.discrete, out.json, out.fig,
                continuous_method=par.assembly["continuous_method"], tolerate=bool(wc.run))
