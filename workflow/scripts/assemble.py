"""Snakemake script: closed-loop LTI assembly and Fig. 4 (ssamb.stages.assemble.run_assemble)."""
import sys
from pathlib import Path

from ssamb.stages.assemble import run_assemble

with open(snakemake.log[0], "w") as log:  # noqa: F821
    sys.stderr = sys.stdout = log
    inp, out = snakemake.input, snakemake.output  # noqa: F821
    run_assemble({Path(p).stem: p for p in inp.models}, {Path(p).stem.replace("_paper", ""): p for p in inp.paper},
                 inp.fig4, snakemake.params.pid, out.discrete, out.json, out.fig,  # noqa: F821
                 continuous_method=snakemake.params.assembly["continuous_method"])  # noqa: F821
