r"""Stage ``mu``: μ over frequency for one uncertainty case (paper sections 4 and 6.2, Fig. 8).

The generalized plant of Fig. 6 (:mod:`ssamb.generalized_plant`) for a case (self-sensing,
amplifier, plant, or all three block-diagonally), :math:`N_{11}` over a log grid refined
around the peak, the structured singular value bounds (:func:`ssamb.mu.mussv`), the peak, its
frequency, the margin and the factor the weights must be scaled by to bring the peak to 1
(the paper needed 0.0012), and the computed cause of the peak
(:func:`ssamb.peak_cause.peak_cause`: least-damped closed-loop poles, weight features, plant
modes, counterfactuals).
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from ..channels import SUBSYSTEMS
from ..generalized_plant import case_structure, uncertainty_loop
from ..io import save_npz, write_json
from ..model_io import load_model, load_weight
from ..peak_cause import peak_cause
from ..robustness import log_grid, mu_for_case
from ..sim.controller import pid_discrete

__all__ = ["run_mu"]


def run_mu(models: Mapping[str, str | Path], weights: Mapping[str, str | Path], case: str,
           pid_params: Mapping, params: Mapping, out_json: str | Path, out_npz: str | Path,
           out_fig: str | Path | None = None) -> dict:
    """μ over frequency for one uncertainty case (Fig. 8) and its margins.

    ``models``: subsystem -> model file; ``weights``: subsystem -> weight file (those of the
    case); ``params`` is the config section ``mu``: ``f_min_hz``, ``f_max_hz``, ``n_points``
    (log grid), ``refine`` (bool).
    """
    pid = pid_discrete(pid_params)
    m = {k: load_model(v) for k, v in models.items()}
    loop = uncertainty_loop(m["plant"], m["amplifier"], m["selfsensing"], pid, pid)
    unknown = sorted(set(weights) - set(SUBSYSTEMS))
    if unknown:
        raise ValueError(f"weights: unknown subsystem '{unknown[0]}' (known: {', '.join(SUBSYSTEMS)})")
    # in the subsystems' order whatever the caller's: the results are byte-reproducible
    w = {k: load_weight(weights[k]) for k in SUBSYSTEMS if k in weights}
    sweep = mu_for_case(loop, w, case, log_grid(params["f_min_hz"], params["f_max_hz"], params["n_points"]),
                        refine=bool(params["refine"]))
    info = {"case": case, "blk": case_structure(case), **sweep.as_dict(),
            "robustly_stable": bool(sweep.peak < 1.0), "weights": sorted(w),
            "peak_cause": peak_cause(loop, w, case, sweep, m["plant"], selfsensing=m["selfsensing"])}
    save_npz(out_npz, {"freqs_hz": np.asarray(sweep.freqs_hz), "upper": np.asarray(sweep.upper),
                       "lower": np.asarray(sweep.lower)}, {"case": case})
    write_json(out_json, info)
    if out_fig is not None:
        from ..figures import fig8

        fig8(sweep, case, out_fig)
    return info
