"""Snakemake script: closed-loop LTI assembly and Fig. 4 (ssamb.assembly_stage.run_assemble)."""
import sys
from pathlib import Path

from ssamb.assembly_stage import run_assemble

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    inp, out = snakemake.input, snakemake.output  # noqa: F821
    models = {Path(p).stem: p for p in inp.models}
    paper = {Path(p).stem.replace("_paper", ""): p for p in inp.paper}
    run_assemble(models, paper, inp.fig4, snakemake.params.pid, out.discrete, out.continuous,  # noqa: F821
                 out.json, out.fig, continuous_method=snakemake.params.assembly["continuous_method"])  # noqa: F821
