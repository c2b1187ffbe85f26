r"""Stage ``baseline``: ISO 14839-3 peak sensitivity per axis and the classical margins (paper
section 1: the de facto robustness measure the paper argues is not sufficient)."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from ..io import write_json
from ..model_io import load_model
from ..robustness import log_grid, sensitivity_baseline
from ..sim.controller import pid_discrete

__all__ = ["run_baseline"]


def run_baseline(models: Mapping[str, str | Path], pid_params: Mapping, params: Mapping,
                 out_json: str | Path) -> dict:
    """Peak sensitivity, its ISO zone and the margins of each axis of the assembled loop.

    ``models``: subsystem -> model file; ``params`` is the config section ``mu`` (its grid).
    """
    m = {k: load_model(v) for k, v in models.items()}
    out = sensitivity_baseline(m["plant"], m["amplifier"], m["selfsensing"], pid_discrete(pid_params),
                               log_grid(params["f_min_hz"], params["f_max_hz"], params["n_points"]))
    write_json(out_json, out)
    return out
