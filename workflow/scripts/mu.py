"""Snakemake script: mu for one uncertainty case (ssamb.stages.mu.run_mu); a failure in a scenario or study run is
recorded in its outputs (ssamb.stages.run_guarded)."""

from ssamb.stages import job_log, run_guarded
from ssamb.stages.mu import run_mu

with job_log(snakemake.log[0], "mu"):  # noqa: F821
    inp, out, wc, par = snakemake.input, snakemake.output, snakemake.wildcards, snakemake.params  # noqa: F821
    models = {"plant": inp.plant_model, "amplifier": inp.amplifier_model, "selfsensing": inp.selfsensing_model}
    weights = {k[2:]: inp[k] for k in sorted(inp.keys()) if k.startswith("w_")}
    run_guarded("mu", out, run_mu, models, weights, wc.case, par.pid, par.mu, out.json, out.curve, out.fig,
                tolerate=bool(wc.run))
