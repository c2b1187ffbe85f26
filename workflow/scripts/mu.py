"""Snakemake script: mu for one uncertainty case (ssamb.stages.mu.run_mu)."""
import sys

from ssamb.stages.mu import run_mu

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    inp, out = snakemake.input, snakemake.output  # noqa: F821
    models = {"plant": inp.plant_model, "amplifier": inp.amplifier_model, "selfsensing": inp.selfsensing_model}
    weights = {k[2:]: inp[k] for k in inp.keys() if k.startswith("w_")}
    run_mu(models, weights, snakemake.wildcards.case, snakemake.params.pid, snakemake.params.mu,  # noqa: F821
           out.json, out.curve, out.fig)
