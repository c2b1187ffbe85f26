r"""Validation of the uncertainty model and of the μ margin (paper section 6.1, Fig. 9).

Augmented model
---------------
"An uncertainty model would be valid if it could be used along with the original nominal model
to duplicate the behaviour of the nonlinear system": the nominal subsystem model
:math:`\bar G` is replaced by :math:`\bar G + W\Delta` (eq. (4)) with :math:`\Delta` a fixed
all-pass -- here :math:`\Delta = +1`, :math:`\Delta = -1` and the first-order all-pass
:math:`\Delta(s) = (1 - s/\omega_a)/(1 + s/\omega_a)` -- and the closed loop is re-assembled.
The additive path acts on the *deviation* of the subsystem input from its operating point
(the weight was measured on the excited lines only; its DC value must not shift the set point):
:math:`y = \bar G u + W\Delta\,(u - u_{op})`.

Sweep test
----------
A sine sweep at the system input (the paper: 99 μm, 11 to 50 Hz) is applied to the nonlinear
simulation, the nominal LTI closed loop and each augmented model. Delevitation is the rotor
reaching the backup-bearing clearance, :math:`\sqrt{x^2 + y^2} \ge c`; its time gives the
instantaneous sweep frequency. Because an LTI model scales linearly with the amplitude, its
critical sweep amplitude is exactly :math:`c / \max_t \|p(t)\|` for the response
:math:`p(t)` per unit amplitude; the nonlinear model's is found by bisection.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

import control
import numpy as np

__all__ = [
    "DELTAS",
    "delta_system",
    "augment_subsystem",
    "first_contact",
    "SweepOutcome",
    "lti_sweep_outcome",
    "critical_amplitude_lti",
    "critical_amplitude_bisect",
    "sweep_models",
    "lti_sweep",
    "nonlinear_critical_amplitude",
]

#: The fixed all-pass choices of Delta reported for the augmented model.
DELTAS = ("plus", "minus", "allpass")


def delta_system(kind: str, dt: float, allpass_hz: float = 20.0) -> control.StateSpace:
    r"""Discrete :math:`\Delta`: ``plus`` (+1), ``minus`` (-1) or ``allpass``
    :math:`(1 - s/\omega_a)/(1 + s/\omega_a)` (Tustin at ``dt``; Tustin preserves :math:`|\Delta| = 1`)."""
    if kind == "plus":
        return control.ss([], [], [], [[1.0]], dt)
    if kind == "minus":
        return control.ss([], [], [], [[-1.0]], dt)
    if kind == "allpass":
        if not allpass_hz > 0:
            raise ValueError(f"allpass_hz must be > 0 (got {allpass_hz})")
        wa = 2 * np.pi * allpass_hz
        s = control.tf("s")
        return control.ss(control.sample_system((1 - s / wa) / (1 + s / wa), dt, method="tustin"))
    raise ValueError(f"delta kind '{kind}': must be one of {', '.join(DELTAS)}")


def augment_subsystem(model: control.StateSpace, weight: control.LTI, input_name: str,
                      output_name: str, u_op: float, delta: str = "plus",
                      allpass_hz: float = 20.0) -> control.StateSpace:
    r"""Augmented subsystem :math:`y = \bar G u + W\Delta(u_k - u_{op})` on one channel pair.

    Parameters
    ----------
    model : control.StateSpace
        Discrete nominal subsystem with named inputs/outputs (an affine model has the input
        ``one``, which is kept).
    weight : control.LTI
        Continuous-time (or discrete at the model's dt) uncertainty weight :math:`W`.
    input_name, output_name : str
        The channel pair on which the additive uncertainty acts (e.g. ``i_ypos`` -> ``y_ss``).
    u_op : float
        Operating point of that input (the path acts on the deviation).
    delta : str
        ``plus``, ``minus`` or ``allpass``.

    Returns
    -------
    control.StateSpace
        Same inputs and outputs as ``model``; discrete at ``model.dt``.
    """
    dt = model.dt
    if not dt:
        raise ValueError("the nominal model must be discrete")
    ins = list(model.input_labels)
    outs = list(model.output_labels)
    if input_name not in ins:
        raise ValueError(f"input '{input_name}' not in the model inputs {ins}")
    if output_name not in outs:
        raise ValueError(f"output '{output_name}' not in the model outputs {outs}")
    w = weight if weight.dt else control.sample_system(control.ss(weight), dt, method="tustin")
    wd = control.ss(w) * delta_system(delta, dt, allpass_hz)
    path = control.ss(wd.A, wd.B, wd.C, wd.D, dt, inputs=["dev"], outputs=["dy"], name="w_delta")
    nominal = control.ss(model.A, model.B, model.C, model.D, dt, inputs=ins,
                         outputs=[o + "_nom" for o in outs], name="nominal")
    blocks = [nominal, path]
    # deviation of the channel input from its operating point
    has_one = "one" in ins
    if has_one:
        dev = control.summing_junction(inputs=[input_name, "one"], output="dev", dt=dt, name="dev")
        dev = control.ss(dev.A, dev.B, dev.C, np.asarray(dev.D) * np.array([[1.0, -u_op]]), dt,
                         inputs=[input_name, "one"], outputs=["dev"], name="dev")
    else:
        dev = control.ss([], [], [], [[1.0]], dt, inputs=[input_name], outputs=["dev"], name="dev")
        if u_op != 0.0:
            raise ValueError("a non-zero operating point needs the affine input 'one' in the model")
    blocks.append(dev)
    for o in outs:
        if o == output_name:
            blocks.append(control.summing_junction(inputs=[o + "_nom", "dy"], output=o, dt=dt, name="s_" + o))
        else:
            blocks.append(control.summing_junction(inputs=[o + "_nom"], output=o, dt=dt, name="s_" + o))
    aug = control.interconnect(blocks, inplist=ins, inputs=ins, outlist=outs, outputs=outs,
                               name=f"{model.name}_aug_{delta}")
    return control.ss(aug.A, aug.B, aug.C, aug.D, dt, inputs=ins, outputs=outs, name=aug.name)


def first_contact(t: np.ndarray, x: np.ndarray, y: np.ndarray, clearance_m: float) -> float | None:
    """First time the radial displacement reaches the clearance (None if never)."""
    r = np.hypot(np.asarray(x, float), np.asarray(y, float))
    idx = np.flatnonzero(r >= clearance_m)
    return float(np.asarray(t)[idx[0]]) if idx.size else None


@dataclass
class SweepOutcome:
    """Result of one model in the sweep test."""

    model: str
    delevitates: bool
    time_s: float | None
    sweep_hz: float | None
    max_radial_m: float
    extra: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"model": self.model, "delevitates": self.delevitates, "time_s": self.time_s,
                "sweep_hz": self.sweep_hz, "max_radial_m": self.max_radial_m, **self.extra}


def lti_sweep_outcome(name: str, out: Mapping[str, np.ndarray], clearance_m: float,
                      freq_at: Callable[[float], float]) -> SweepOutcome:
    """Delevitation of an LTI closed-loop response (plant outputs ``x_meas``, ``y_meas``)."""
    t = np.asarray(out["t"], float)
    x = np.asarray(out["x_meas"], float)
    y = np.asarray(out["y_meas"], float)
    tc = first_contact(t, x, y, clearance_m)
    return SweepOutcome(name, tc is not None, tc, None if tc is None else float(freq_at(tc)),
                        float(np.max(np.hypot(x, y))))


def critical_amplitude_lti(x_per_unit: np.ndarray, y_per_unit: np.ndarray, x_op: float, y_op: float,
                           clearance_m: float) -> float:
    r"""Sweep amplitude at which a linear model first reaches the clearance.

    With the response to a unit-amplitude sweep :math:`p(t)` about the operating point
    :math:`p_0`, the response to amplitude :math:`a` is :math:`p_0 + a\,p(t)`; the smallest
    :math:`a` with :math:`\max_t \|p_0 + a p(t)\| = c` is found per sample from the quadratic
    :math:`\|p_0 + a p\|^2 = c^2` (positive root), then minimised over t.
    """
    px = np.asarray(x_per_unit, float)
    py = np.asarray(y_per_unit, float)
    a2 = px**2 + py**2
    b = 2 * (x_op * px + y_op * py)
    c0 = x_op**2 + y_op**2 - clearance_m**2
    if c0 >= 0:
        return 0.0
    ok = a2 > 0
    disc = b[ok] ** 2 - 4 * a2[ok] * c0
    roots = (-b[ok] + np.sqrt(disc)) / (2 * a2[ok])
    return float(np.min(roots)) if roots.size else float("inf")


def critical_amplitude_bisect(delevitates: Callable[[float], bool], lo: float, hi: float,
                              rel_tol: float = 0.02, max_iter: int = 20, lo_min: float | None = None) -> dict:
    """Smallest amplitude in ``[lo_min, hi]`` for which ``delevitates(a)`` is True (bisection).

    Assumes monotonicity (a larger sweep amplitude never stabilises the rotor). The bracket's
    lower end must levitate: where ``lo`` already delevitates it is halved until it levitates,
    down to ``lo_min`` (default ``lo / 16``), so the lower end of the search is never reported as
    the critical amplitude. Returns ``{"amplitude_m": a or None, "bracket": [a_lo, a_hi],
    "evaluations": n, "below_search": bool}``: ``amplitude_m`` None when even ``hi`` does not
    delevitate; ``below_search`` True (and ``amplitude_m`` None) when even ``lo_min`` does, the
    critical amplitude then lying below the bracket ``[0, lo_min]``.
    """
    if not 0 < lo < hi:
        raise ValueError(f"need 0 < lo < hi (got {lo}, {hi})")
    lo_min = lo / 16.0 if lo_min is None else float(lo_min)
    n = 1
    if not delevitates(hi):
        return {"amplitude_m": None, "bracket": [lo, hi], "evaluations": n, "below_search": False}
    a, b = lo, hi
    n += 1
    while delevitates(a):
        b = a
        if a <= lo_min or n >= max_iter:
            return {"amplitude_m": None, "bracket": [0.0, a], "evaluations": n, "below_search": True}
        a = max(0.5 * a, lo_min)
        n += 1
    while b - a > rel_tol * b and n < max_iter:
        mid = 0.5 * (a + b)
        n += 1
        if delevitates(mid):
            b = mid
        else:
            a = mid
    return {"amplitude_m": b, "bracket": [a, b], "evaluations": n, "below_search": False}


def sweep_models(plant, amplifier, selfsensing, weight: control.LTI, pid, allpass_hz: float) -> dict:
    """The nominal closed loop and the augmented ones (self-sensing + :math:`W\\Delta` for each
    :data:`DELTAS`), by name (``nominal LTI``, ``augmented, Delta=<kind>``)."""
    from .channels import ONE
    from .closed_loop import assemble_closed_loop

    ss_sys = selfsensing.to_statespace()
    ss_in = [c for c in selfsensing.input_names if c != ONE][0]
    u_op = float(selfsensing.u_op[0]) if selfsensing.u_op is not None else 0.0
    systems = {"nominal LTI": assemble_closed_loop(plant, amplifier, ss_sys, pid, pid)}
    for d in DELTAS:
        aug = augment_subsystem(ss_sys, weight, ss_in, "y_ss", u_op, delta=d, allpass_hz=allpass_hz)
        systems[f"augmented, Delta={d}"] = assemble_closed_loop(plant, amplifier, aug, pid, pid)
    return systems


def lti_sweep(name: str, cl: control.StateSpace, ref: Mapping[str, np.ndarray], amplitude_m: float,
              clearance_m: float, freq_at: Callable[[float], float]) -> tuple[SweepOutcome, dict | None]:
    """Sweep response of one LTI closed loop driven by the recorded references ``ref`` (``t``,
    ``r_x``, ``r_y``) from its operating point: its outcome (delevitation time and sweep
    frequency, and the exact critical amplitude of :func:`critical_amplitude_lti`) and the
    response (None for an unstable loop, whose outcome notes it)."""
    from .closed_loop import lti_initial_state, simulate_closed_loop, stability

    rep = stability(cl)
    if not rep.stable:
        return SweepOutcome(name, False, None, None, float("nan"),
                            {"note": f"LTI model unstable ({rep}): no sweep response"}), None
    x0 = lti_initial_state(cl, float(ref["r_x"][0]), float(ref["r_y"][0]))
    out = simulate_closed_loop(cl, ref["t"], ref["r_x"], ref["r_y"], x0=x0)
    oc = lti_sweep_outcome(name, out, clearance_m, freq_at)
    if amplitude_m > 0:  # response per unit sweep amplitude about the operating point
        x_op, y_op = float(out["x_meas"][0]), float(out["y_meas"][0])
        oc.extra["critical_amplitude_m"] = critical_amplitude_lti(
            (np.asarray(out["x_meas"]) - x_op) / amplitude_m, (np.asarray(out["y_meas"]) - y_op) / amplitude_m,
            x_op, y_op, clearance_m)
    return oc, out


def nonlinear_critical_amplitude(sim_cfg: Mapping, experiment: str, clearance_m: float, amplitude_max_m: float,
                                 rel_tol: float) -> dict:
    """Bisection (:func:`critical_amplitude_bisect`) over nonlinear simulations of the sweep
    experiment with its amplitude changed, from a quarter of the clearance (lower where that
    already delevitates) to ``amplitude_max_m``."""
    from .sim import simulate

    spec = sim_cfg["experiments"][experiment]

    def delevitates(a: float) -> bool:
        exc = {**spec["excitation"], "amplitude_m": float(a)}
        res = simulate(sim_cfg, experiment, excitation=exc, duration_s=spec["duration_s"], progress=False)
        return res.meta["delevitation_s"] is not None

    return critical_amplitude_bisect(delevitates, 0.25 * clearance_m, float(amplitude_max_m), rel_tol=float(rel_tol))
