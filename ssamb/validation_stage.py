r"""The ``validate`` stage: the augmented model and the delevitation sweep (section 6, Fig. 9).

:func:`run_validate` applies the recorded sweep reference of the nonlinear run
(``results/sim/sweep.npz``) to the nominal closed-loop LTI model and to the augmented models
(the self-sensing model plus :math:`W\Delta` with :math:`\Delta = +1, -1` and a first-order
all-pass, :mod:`ssamb.validation`), detects delevitation (radial displacement reaching the
backup-bearing clearance) in each, and reports the time and the instantaneous sweep frequency.
Because the LTI models respond linearly, their critical sweep amplitude is exact
(:func:`ssamb.validation.critical_amplitude_lti`); the nonlinear model's is found by bisection
over the sweep amplitude, each step a simulation.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from .assembly_stage import lti_initial_state
from .ident import load_model
from .io import load_npz, write_json
from .robustness_stage import load_weight
from .validation import (DELTAS, SweepOutcome, augment_subsystem, critical_amplitude_bisect,
                         critical_amplitude_lti, lti_sweep_outcome)

__all__ = ["run_validate"]


def run_validate(sweep_npz: str | Path, models: Mapping[str, str | Path], weight_npz: str | Path,
                 sim_cfg: Mapping, params: Mapping, out_json: str | Path, out_fig: str | Path | None = None,
                 progress: bool = False) -> dict:
    """Sweep validation of the nominal and augmented LTI models against the nonlinear model.

    ``params``: ``allpass_hz`` (corner of the all-pass Delta), ``amplitude_search`` (bool),
    ``amplitude_max_m`` (upper end of the bisection), ``rel_tol``; ``sim_cfg`` is the simulator
    config including ``experiments.sweep`` (for the bisection runs).
    """
    from .loop import assemble_closed_loop, simulate_closed_loop
    from .signals import sweep_frequency_at
    from .sim import simulate
    from .sim.controller import pid_discrete

    nl, meta = load_npz(sweep_npz)
    exc = meta["excitation"]
    axis = exc.get("axis", "y")
    f0, f1, tsw, law = (float(exc["f_start_hz"]), float(exc["f_stop_hz"]), float(exc["sweep_duration_s"]),
                        exc.get("law", "linear"))

    def freq_at(t):
        return float(sweep_frequency_at(np.asarray([t]), f0, f1, tsw, law)[0])

    clearance = float(sim_cfg["table1"]["backup_clearance_m"])
    t = np.asarray(nl["t"], float)
    pid = pid_discrete(sim_cfg)
    m = {k: load_model(v) for k, v in models.items()}
    w = load_weight(weight_npz)
    ss = m["selfsensing"]
    ss_sys = ss.to_statespace()
    ss_in = list(ss.input_names)[0]
    u_op = float(ss.u_op[0]) if ss.u_op is not None else 0.0
    outcomes: list[SweepOutcome] = []
    responses = {"nonlinear": {"x": nl["x_true"], "y": nl["y_true"]}}
    tc = meta.get("delevitation_s")
    outcomes.append(SweepOutcome("nonlinear", tc is not None, tc, None if tc is None else freq_at(tc),
                                 float(np.max(np.hypot(nl["x_true"], nl["y_true"])))))
    amp = float(exc.get("amplitude_m", 0.0))
    ref_axis = {"x": nl["r_x"], "y": nl["r_y"]}
    per_unit = {}
    systems = {"nominal LTI": assemble_closed_loop(m["plant"], m["amplifier"], ss_sys, pid, pid)}
    for d in DELTAS:
        aug = augment_subsystem(ss_sys, w, ss_in, "y_ss", u_op, delta=d, allpass_hz=float(params["allpass_hz"]))
        systems[f"augmented, Delta={d}"] = assemble_closed_loop(m["plant"], m["amplifier"], aug, pid, pid)
    for name, cl in systems.items():
        from .loop import stability

        rep = stability(cl)
        if not rep.stable:
            outcomes.append(SweepOutcome(name, False, None, None, float("nan"),
                                         {"note": f"LTI model unstable ({rep}): no sweep response"}))
            continue
        x0 = lti_initial_state(cl, float(nl["r_x"][0]), float(nl["r_y"][0]))
        out = simulate_closed_loop(cl, t, nl["r_x"], nl["r_y"], x0=x0)
        oc = lti_sweep_outcome(name, out, clearance, freq_at)
        # response per unit sweep amplitude (about the operating point) -> exact critical amplitude
        x_op = float(out["x_meas"][0])
        y_op = float(out["y_meas"][0])
        if amp > 0:
            px = (np.asarray(out["x_meas"]) - x_op) / amp
            py = (np.asarray(out["y_meas"]) - y_op) / amp
            oc.extra["critical_amplitude_m"] = critical_amplitude_lti(px, py, x_op, y_op, clearance)
        outcomes.append(oc)
        responses[name] = {"x": out["x_meas"], "y": out["y_meas"]}
        per_unit[name] = None
    # nonlinear critical amplitude by bisection over simulations
    search = None
    if bool(params.get("amplitude_search", True)):
        base_exc = dict(sim_cfg["experiments"]["sweep"]["excitation"])
        dur = sim_cfg["experiments"]["sweep"]["duration_s"]

        def delevitates(a: float) -> bool:
            e = dict(base_exc)
            e["amplitude_m"] = float(a)
            res = simulate(sim_cfg, "sweep", excitation=e, duration_s=dur, progress=False)
            return res.meta["delevitation_s"] is not None

        search = critical_amplitude_bisect(delevitates, 0.25 * clearance, float(params["amplitude_max_m"]),
                                           rel_tol=float(params["rel_tol"]))
        outcomes[0].extra["critical_amplitude_m"] = search["amplitude_m"]
    info = {
        "sweep": {"amplitude_m": amp, "f_start_hz": f0, "f_stop_hz": f1, "sweep_duration_s": tsw,
                  "law": law, "axis": axis},
        "clearance_m": clearance,
        "outcomes": [o.as_dict() for o in outcomes],
        "nonlinear_amplitude_search": search,
        "delevitation_s": {
            "nonlinear": outcomes[0].time_s,
            "nominal_lti": next(o.time_s for o in outcomes if o.model == "nominal LTI"),
            "augmented_lti": {o.model: o.time_s for o in outcomes if o.model.startswith("augmented")},
        },
    }
    write_json(out_json, info)
    if out_fig is not None:
        from .figures import fig9

        fig9(t, responses, clearance, sweep_frequency_at(t, f0, f1, tsw, law), out_fig)
    return info
