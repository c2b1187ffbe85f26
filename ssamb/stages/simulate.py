"""Stage ``simulate``: one experiment of the nonlinear self-sensing AMB (paper section 2.2)."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from ..config import validate_config
from ..sim import simulate

__all__ = ["run_simulate"]


def run_simulate(cfg: Mapping, experiment: str, out_npz: str | Path, progress: bool = False) -> dict:
    """Validate ``cfg``, simulate ``experiment`` and write ``out_npz`` with its JSON sidecar
    (:meth:`ssamb.sim.SimResult.save`); returns the run's meta."""
    validate_config(cfg)
    result = simulate(cfg, experiment, progress=progress)
    result.save(out_npz)
    return result.meta
