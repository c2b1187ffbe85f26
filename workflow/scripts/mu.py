"""Snakemake script: mu for one uncertainty case (ssamb.robustness_stage.run_mu)."""
import os
import sys

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # small matrices: single-threaded BLAS is faster and stable

from ssamb.robustness_stage import run_mu  # noqa: E402

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    inp, out = snakemake.input, snakemake.output  # noqa: F821
    models = {"plant": inp.plant_model, "amplifier": inp.amplifier_model, "selfsensing": inp.selfsensing_model}
    weights = {k[2:]: inp[k] for k in inp.keys() if k.startswith("w_")}
    run_mu(models, weights, snakemake.wildcards.case, snakemake.params.pid, snakemake.params.mu,  # noqa: F821
           out.json, out.curve, out.fig)
