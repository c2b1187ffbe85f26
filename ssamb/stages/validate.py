r"""Stage ``validate``: the augmented models and the delevitation sweep (paper section 6, Fig. 9).

The recorded sweep reference of the nonlinear run drives the nominal closed-loop LTI model and
the augmented models (the self-sensing model plus :math:`W\Delta` with :math:`\Delta = +1, -1`
and a first-order all-pass, :func:`ssamb.validation.sweep_models`); delevitation (radial
displacement reaching the backup-bearing clearance) is detected in each, with its time and
instantaneous sweep frequency. The LTI models' critical sweep amplitudes are exact; the
nonlinear model's is found by bisection over simulations.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from ..io import write_json
from ..model_io import load_model, load_record, load_weight
from ..signals import sweep_frequency_at
from ..sim.controller import pid_discrete
from ..validation import (
    SweepOutcome,
    lti_sweep,
    nonlinear_critical_amplitude,
    sweep_models,
)

__all__ = ["run_validate"]


def run_validate(sweep_npz: str | Path, models: Mapping[str, str | Path], weight_npz: str | Path,
                 sim_cfg: Mapping, params: Mapping, out_json: str | Path, out_fig: str | Path | None = None,
                 experiment: str = "sweep") -> dict:
    """Sweep validation of the nominal and augmented LTI models against the nonlinear model.

    ``params`` is the config section ``validation``: ``allpass_hz`` (corner of the all-pass
    Delta), ``amplitude_search`` (bool), ``amplitude_max_m`` (upper end of the bisection),
    ``rel_tol``; ``sim_cfg`` is the simulator config including ``experiments.<experiment>``.
    """
    nl, meta = load_record(sweep_npz)
    exc = meta["excitation"]
    law = (float(exc["f_start_hz"]), float(exc["f_stop_hz"]), float(exc["sweep_duration_s"]), exc.get("law", "linear"))

    def freq_at(t):
        return float(sweep_frequency_at(np.asarray([t]), *law)[0])

    clearance = float(sim_cfg["table1"]["backup_clearance_m"])
    amp = float(exc.get("amplitude_m", 0.0))
    tc = meta.get("delevitation_s")
    outcomes = [SweepOutcome("nonlinear", tc is not None, tc, None if tc is None else freq_at(tc),
                             float(np.max(np.hypot(nl["x_true"], nl["y_true"]))))]
    responses = {"nonlinear": {"x": nl["x_true"], "y": nl["y_true"]}}
    m = {k: load_model(v) for k, v in models.items()}
    systems = sweep_models(m["plant"], m["amplifier"], m["selfsensing"], load_weight(weight_npz),
                           pid_discrete(sim_cfg), float(params["allpass_hz"]))
    for name, cl in systems.items():
        oc, out = lti_sweep(name, cl, nl, amp, clearance, freq_at)
        outcomes.append(oc)
        if out is not None:
            responses[name] = {"x": out["x_meas"], "y": out["y_meas"]}
    search = None
    if bool(params.get("amplitude_search", True)):
        search = nonlinear_critical_amplitude(sim_cfg, experiment, clearance, params["amplitude_max_m"],
                                              params["rel_tol"])
        outcomes[0].extra["critical_amplitude_m"] = search["amplitude_m"]
    info = {
        "sweep": {"amplitude_m": amp, "f_start_hz": law[0], "f_stop_hz": law[1], "sweep_duration_s": law[2],
                  "law": law[3], "axis": exc.get("axis", "y")},
        "clearance_m": clearance, "outcomes": [o.as_dict() for o in outcomes],
        "nonlinear_amplitude_search": search,
        "delevitation_s": {
            "nonlinear": outcomes[0].time_s,
            "nominal_lti": next(o.time_s for o in outcomes if o.model == "nominal LTI"),
            "augmented_lti": {o.model: o.time_s for o in outcomes if o.model.startswith("augmented")},
        },
    }
    write_json(out_json, info)
    if out_fig is not None:
        from ..figures import fig9

        fig9(nl["t"], responses, clearance, sweep_frequency_at(np.asarray(nl["t"], float), *law), out_fig)
    return info
