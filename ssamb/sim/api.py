"""The simulator's Python API: :func:`simulate` and its helpers.

:func:`simulate` builds the excitation of an experiment named in the configuration (or takes
explicit reference/injection arrays), applies effects and noise, computes the levitated
equilibrium, calibrates DCM self-sensing, runs the compiled kernel with a progress bar and
returns a :class:`SimResult` whose ``data`` is in the measured-data format (ARCHITECTURE.md)
plus the true states (``x_true``, ``y_true``, ``b_*_t``, ``duty_*``, ``contact``, ...).
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np
from scipy.optimize import brentq

from .. import COILS
from ..config import ConfigError, config_hash
from .effects import apply_effects
from .kernel import (N_OUT, OUT_NAMES, RING, S_DUTY, S_INTEG, S_M, S_PHASE, S_PHI, S_PIDX_E,
                     S_PIDX_I, S_PIDY_E, S_PIDY_I, S_SSF, S_SSLP, S_TCONTACT, S_VOLT, S_X, S_Y,
                     S_XS, new_state, run_chunk, trend_basis)
from .magnetics import MAX_PLAY, flux_from_current, force_from_flux, gap_sum
from .params import AMBParams, P_HYST, amb_params

__all__ = ["SimResult", "simulate", "equilibrium", "calibrate_selfsensing", "excitation_arrays",
           "force_arrays", "noise_arrays", "delevitation_time"]


@dataclass
class SimResult:
    """Output of :func:`simulate`.

    Attributes
    ----------
    data : dict of arrays
        Measured-data columns at ``fs_hz`` (``t`` starts at 0 after the pre-roll) and true states.
    meta : dict
        Excitation, seeds, calibration, config hash, timings, delevitation.
    ripple : dict of arrays
        ``t`` (period start), ``i_max``, ``i_min`` of the ypos current in every PWM period.
    fine : dict of arrays or None
        ``t`` and the four currents at every integration sub-step (``record_fine=True``).
    """

    data: dict
    meta: dict
    ripple: dict
    fine: dict | None = None

    def save(self, path: str | Path) -> None:
        """Write ``data`` (+ ripple, fine) to an NPZ file with a JSON sidecar (atomic)."""
        from ..io import save_npz

        arrays = dict(self.data)
        arrays.update({"ripple_" + k: v for k, v in self.ripple.items()})
        if self.fine is not None:
            arrays.update({"fine_" + k: v for k, v in self.fine.items()})
        save_npz(path, arrays, self.meta)


# ------------------------------------------------------------------------------------------
def equilibrium(par: AMBParams, packed: np.ndarray, f_x_n: float = 0.0, f_y_n: float = 0.0,
                x_m: float = 0.0, y_m: float = 0.0) -> dict:
    """Static equilibrium of the levitated rotor at ``(x_m, y_m)`` under an external force.

    Solves for the differential control currents :math:`u_x, u_y` such that the magnetic force
    balances gravity and the external force, :math:`F_y(i_0+u_y, i_0-u_y) = m g - f_y`,
    :math:`F_x(i_0+u_x, i_0-u_x) = -f_x`, with the static (hysteresis-free) magnetic circuit.
    Returns currents, fluxes, the control currents and the steady duty cycles.
    """
    p = packed.copy()
    p[P_HYST] = 0.0
    z = np.zeros(MAX_PLAY)
    disp = (y_m, -y_m, x_m, -x_m)
    i0 = par.i_bias_a

    def phi_of(j, i):
        return flux_from_current(max(i, 0.0), gap_sum(disp[j], p), z, p)

    def fy(u):
        return force_from_flux(phi_of(0, i0 + u), p) - force_from_flux(phi_of(1, i0 - u), p)

    def fx(u):
        return force_from_flux(phi_of(2, i0 + u), p) - force_from_flux(phi_of(3, i0 - u), p)

    ty = par.mass_kg * par.gravity_m_per_s2 - f_y_n
    tx = -f_x_n
    lim = min(par.u_max_a, i0) * 0.999
    try:
        uy = brentq(lambda u: fy(u) - ty, -lim, lim, xtol=1e-12)
        ux = brentq(lambda u: fx(u) - tx, -lim, lim, xtol=1e-12)
    except ValueError:
        raise ConfigError(
            f"no levitated equilibrium: the control current would exceed u_max_a = {par.u_max_a} A "
            f"(load {tx:.3g} N in x, {ty:.3g} N in y)") from None
    cur = np.array([i0 + uy, i0 - uy, i0 + ux, i0 - ux])
    phis = np.array([phi_of(j, cur[j]) for j in range(4)])
    duty = 0.5 + par.r_coil_ohm * cur / (2 * par.v_supply_v)
    return {"u_x": ux, "u_y": uy, "currents_a": cur, "phi_wb": phis, "duty": duty}


def _init_state(par: AMBParams, packed: np.ndarray, start: str, eq: dict | None):
    st, z, ring_i, ring_d, ring_s, ring_x, ring_y = new_state()
    for j in range(4):
        st[S_M + j] = -1.0     # first PWM period starts at t = 0
        st[S_PHASE + j] = 2.0
        st[S_VOLT + j] = -1.0
    if start == "levitated":
        st[S_X] = 0.0 if eq is None else eq.get("x_m", 0.0)
        st[S_Y] = 0.0 if eq is None else eq.get("y_m", 0.0)
        st[S_XS] = st[S_X]
        for j in range(4):
            st[S_PHI + j] = eq["phi_wb"][j]
            st[S_INTEG + j] = eq["duty"][j] - 0.5
            st[S_DUTY + j] = eq["duty"][j]
            z[j, :] = eq["phi_wb"][j] / par.pole_area_m2
        st[S_PIDX_I] = eq["u_x"]
        st[S_PIDY_I] = eq["u_y"]
        st[S_SSLP] = st[S_Y]
        st[S_SSF:S_SSF + 4] = st[S_Y]
        ring_x[:] = st[S_X]
        ring_y[:] = st[S_Y]
    elif start == "rest":
        st[S_Y] = -(par.clearance_m + par.mass_kg * par.gravity_m_per_s2 / par.contact_stiffness_n_per_m)
        st[S_XS] = 0.0
        for j in range(4):
            st[S_DUTY + j] = 0.5
    else:
        raise ConfigError(f"experiment start '{start}': must be 'rest' or 'levitated'")
    st[S_PIDX_E] = 0.0
    st[S_PIDY_E] = 0.0
    return st, z, ring_i, ring_d, ring_s, ring_x, ring_y


def _run(par, packed, start, eq, r_x, r_y, inj_x, inj_y, f_x, f_y, n_x, n_ym, n_i,
         record_fine=False, progress=False, desc="simulate", track_ripple=False):
    n = len(r_x)
    st, z, ring_i, ring_d, ring_s, ring_x, ring_y = _init_state(par, packed, start, eq)
    out = np.zeros((N_OUT, n))
    nsub = int(par.substeps)
    fine = np.zeros((13, n * nsub if record_fine else 0))
    n_per = int(n / par.fs_hz * par.f_pwm_hz) + 4 if track_ripple else 0
    rip = np.zeros((3, n_per))
    rip_n = 0
    chunk = max(1, int(par.fs_hz * 0.05))
    tb = trend_basis(par.ss_window, par.ss_trend_order)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n / par.fs_hz, unit="s(sim)", desc=desc, file=sys.stderr,
                   bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.2f}/{total:.2f} s simulated [{elapsed}<{remaining}]")
    for k0 in range(0, n, chunk):
        k1 = min(n, k0 + chunk)
        rip_n = run_chunk(packed, st, z, ring_i, ring_d, ring_s, ring_x, ring_y, tb, k0, k1,
                          r_x, r_y, inj_x, inj_y, f_x, f_y, n_x, n_ym, n_i, out, fine, rip, rip_n)
        if bar is not None:
            bar.update((k1 - k0) / par.fs_hz)
    if bar is not None:
        bar.close()
    return out, fine, rip[:, :rip_n], st


def calibrate_selfsensing(par: AMBParams, packed: np.ndarray, positions_m: Iterable[float],
                          settle_s: float = 0.005, average_samples: int = 833) -> dict:
    """Calibrate the DCM estimator (gain and offset of eq. (2)) with the rotor clamped.

    At every calibration position the rotor is held (as on a calibration rig), the amplifiers
    are driven at the currents that would levitate it there, and the raw estimate is averaged
    over ``average_samples`` (833 samples at 83.3 kHz = 300 PWM periods = one full cycle of the
    sampling-phase pattern, since 83 300/30 000 = 833/300). The least-squares line
    ``y_true = gain * y_raw + offset`` is returned.
    """
    positions = np.asarray(list(positions_m), float)
    raws = []
    fs = par.fs_hz
    n_settle = int(round(settle_s * fs))
    n = n_settle + average_samples
    zeros = np.zeros(n)
    for ypos in positions:
        p = packed.copy()
        from .params import P_CLAMP, P_CLAMP_Y, P_PID_ON, P_SS_GAIN, P_SS_OFF

        p[P_CLAMP] = 1.0
        p[P_CLAMP_Y] = ypos
        p[P_PID_ON] = 0.0
        p[P_SS_GAIN] = 1.0
        p[P_SS_OFF] = 0.0
        eq = equilibrium(par, p, y_m=ypos)
        eq["y_m"] = ypos
        inj_x = np.full(n, eq["u_x"])
        inj_y = np.full(n, eq["u_y"])
        out, _, _, _ = _run(par, p, "levitated", eq, zeros, zeros, inj_x, inj_y, zeros, zeros,
                            zeros, zeros, np.zeros((4, n)))
        raws.append(out[OUT_NAMES.index("y_ss_raw"), n_settle:].mean())
    raws = np.asarray(raws)
    gain, offset = np.polyfit(raws, positions, 1)
    resid = positions - (gain * raws + offset)
    return {"gain": float(gain), "offset_m": float(offset), "positions_m": positions.tolist(),
            "raw_m": raws.tolist(), "max_residual_m": float(np.max(np.abs(resid)))}


def excitation_arrays(spec: Mapping, fs_hz: float, duration_s: float | None, seed: int):
    """Reference and injection arrays for an excitation spec (see :func:`ssamb.signals.make_excitation`).

    ``point: position`` drives the position references, ``point: current`` the current
    injection just before the amplifiers; ``axis: both`` drives x with ``seed`` and y with
    ``seed + 7919`` (independent realisations; the same shift applies to a ``seed`` given in
    the spec itself). Returns ``(duration_s, arrays, info)`` where
    ``info`` holds what a data file's ``meta`` must record to regenerate the excitation.
    """
    from .. import signals

    kind = spec.get("kind", "none")
    point = spec.get("point", "position")
    axis = spec.get("axis", "y")
    if point not in ("position", "current"):
        raise ConfigError(f"excitation key 'point': must be 'position' or 'current' (got {point!r})")
    if axis not in ("x", "y", "both"):
        raise ConfigError(f"excitation key 'axis': must be x, y or both (got {axis!r})")
    axes = ("x", "y") if axis == "both" else (axis,)
    sigs = {}
    info: dict[str, Any] = {"seed": seed, "axis_seeds": {}}
    for a_i, ax in enumerate(axes):
        spec_ax = dict(spec)
        if "seed" in spec_ax:   # a seed in the spec takes precedence in make_excitation
            spec_ax["seed"] = int(spec_ax["seed"]) + 7919 * a_i
        try:
            exc = signals.make_excitation(spec_ax, fs_hz, duration_s, seed + 7919 * a_i)
        except ValueError as err:
            raise ConfigError(str(err)) from None
        sigs[ax] = np.asarray(exc.x, float)
        info["axis_seeds"][ax] = exc.seed
        if exc.multisine is not None:
            ms = exc.multisine
            info["lines_hz"] = [float(f) for f in ms.lines_hz]
            info["samples_per_period"] = int(ms.samples_per_period)
    n = len(next(iter(sigs.values())))
    duration_s = n / fs_hz
    z = np.zeros(n)
    arrs = {"r_x": z.copy(), "r_y": z.copy(), "inj_x": z.copy(), "inj_y": z.copy()}
    if kind != "none":
        for ax, x in sigs.items():
            arrs[("r_" if point == "position" else "inj_") + ax] = x
    return duration_s, arrs, info


def force_arrays(spec: Mapping, fs_hz: float, n: int, seed: int):
    """External force on the rotor from an excitation spec (``amplitude_n`` in newtons).

    An identification aid: force pulses move the rotor independently of the controller's
    commands, which makes the amplifier's dependence on position identifiable from closed-loop
    data (with injections alone the positions are causal functions of past commands). The
    force is not a logged signal. ``axis: both`` uses independent realisations per axis.
    Returns ``(f_x, f_y, info)``.
    """
    from .. import signals

    spec = dict(spec)
    if "amplitude_n" not in spec:
        raise ConfigError("force excitation: key 'amplitude_n' missing")
    axis = spec.pop("axis", "y")
    spec["amplitude_a"] = spec.pop("amplitude_n")   # make_excitation's amplitude (unit label only)
    spec.pop("point", None)
    axes = ("x", "y") if axis == "both" else (axis,)
    out = {"x": np.zeros(n), "y": np.zeros(n)}
    for a_i, ax in enumerate(axes):
        sp = dict(spec)
        if "seed" in sp:
            sp["seed"] = int(sp["seed"]) + 7919 * a_i
        try:
            exc = signals.make_excitation(sp, fs_hz, n / fs_hz, seed + 104729 + 7919 * a_i)
        except ValueError as err:
            raise ConfigError(f"force excitation: {err}") from None
        out[ax] = np.asarray(exc.x, float)[:n]
    return out["x"], out["y"], {"axis": axis, **{k: v for k, v in spec.items()}}


def noise_arrays(noise: Mapping | None, n: int):
    """Gaussian sensor noise: x probe and y evaluation sensor (``position_m`` rms), the four
    current measurements (``current_a`` rms); seeded by ``noise['seed']``. The noise enters the
    loop (the controller sees the noisy sensors), as on a rig."""
    if not noise:
        return np.zeros(n), np.zeros(n), np.zeros((4, n))
    rng = np.random.default_rng(int(noise.get("seed", 0)))
    sp = float(noise.get("position_m", 0.0))
    si = float(noise.get("current_a", 0.0))
    return rng.normal(0, sp, n), rng.normal(0, sp, n), rng.normal(0, si, (4, n))


def delevitation_time(t: np.ndarray, contact: np.ndarray, start: str = "levitated") -> float | None:
    """First time the rotor reaches the backup bearing clearance after having levitated.

    For a ``rest`` start the rotor must first lift off; returns None if it never delevitates.
    """
    contact = np.asarray(contact) > 0.5
    if start == "rest":
        free = np.flatnonzero(~contact)
        if free.size == 0:
            return None
        contact = contact.copy()
        contact[: free[0]] = False
    idx = np.flatnonzero(contact)
    return float(t[idx[0]]) if idx.size else None


def simulate(cfg: Mapping, experiment: str | None = None, *, duration_s: float | None = None,
             excitation: Mapping | None = None, start: str | None = None,
             effects: Iterable[Mapping] = (), noise: Mapping | None = None, seed: int | None = None,
             substeps: int | None = None, record_fine: bool = False, track_ripple: bool = False,
             progress: bool | None = None,
             pid_on: bool = True, clamp_m: tuple[float, float] | None = None,
             arrays: Mapping[str, np.ndarray] | None = None,
             effects_base_dir: str | Path | None = None, settle_s: float | None = None) -> SimResult:
    """Simulate the nonlinear self-sensing AMB.

    Parameters
    ----------
    cfg : mapping
        Validated configuration (:func:`ssamb.config.load_config`).
    experiment : str, optional
        Name of an experiment in ``cfg['experiments']`` (duration, start and excitation).
    duration_s, excitation, start :
        Override or replace the experiment's fields.
    effects : iterable of mappings
        Effects of the close-the-loop library (:mod:`ssamb.sim.effects`).
    noise : mapping, optional
        ``{position_m, current_a, seed}`` sensor noise entering the loop.
    seed : int, optional
        Base seed of the excitation (default ``cfg['seed']``; the experiment's ``seed_offset`` is
        added by :func:`ssamb.signals.make_excitation`).
    substeps : int, optional
        Integration sub-steps per controller sample (default ``simulation.substeps``).
    record_fine : bool
        Also return the currents at every sub-step.
    track_ripple : bool
        Record the maximum and minimum ypos current of every PWM period (exact, at the edges).
    pid_on : bool
        False switches the position controller off (amplifiers keep the bias references).
    clamp_m : (x, y), optional
        Hold the rotor at this position (as on a calibration or magnetics test rig).
    arrays : mapping, optional
        Explicit ``r_x``, ``r_y``, ``inj_x``, ``inj_y`` arrays (replace the excitation).
    """
    t_wall = time.perf_counter()
    exp = dict(cfg["experiments"][experiment]) if experiment is not None else {}
    if experiment is not None and experiment not in cfg["experiments"]:
        raise ConfigError(f"experiment '{experiment}': not in config (known: {', '.join(cfg['experiments'])})")
    if duration_s is not None:
        exp["duration_s"] = duration_s
    if excitation is not None:
        exp["excitation"] = dict(excitation)
    if start is not None:
        exp["start"] = start
    exp.setdefault("start", "levitated")
    exp.setdefault("excitation", {"kind": "none"})
    exp.setdefault("duration_s", None)
    c = dict(cfg)
    if substeps is not None:
        c = {**cfg, "simulation": {**cfg["simulation"], "substeps": int(substeps)}}
    par = amb_params(c)
    fs = par.fs_hz
    exc = exp["excitation"]
    if seed is None:
        seed = int(cfg["seed"])   # make_excitation adds the experiment's seed_offset
    if arrays is not None:
        n = len(next(iter(arrays.values())))
        sig = {k: np.asarray(arrays.get(k, np.zeros(n)), float) for k in ("r_x", "r_y", "inj_x", "inj_y")}
        dur = n / fs
        info = {}
    else:
        dur, sig, info = excitation_arrays(exc, fs, exp["duration_s"], seed)
    n = len(sig["r_x"])
    if n < 1:
        raise ConfigError(f"experiment '{experiment}': duration {dur} s gives no samples")
    settle = cfg["simulation"]["settle_s"] if settle_s is None else settle_s
    if exp["start"] == "rest":
        settle = 0.0
    n_settle = int(round(settle * fs))
    n_tot = n_settle + n
    t_all = (np.arange(n_tot) - n_settle) / fs

    def padded(a, fill=None):
        head = np.full(n_settle, a[0] if fill is None else fill)
        return np.ascontiguousarray(np.concatenate([head, a]))

    ov, f_x, f_y = apply_effects(effects, np.maximum(t_all, 0.0), effects_base_dir)
    force_info = None
    if exp.get("force"):
        fxs, fys, force_info = force_arrays(exp["force"], fs, n, seed)
        f_x = f_x + np.concatenate([np.zeros(n_settle), fxs])
        f_y = f_y + np.concatenate([np.zeros(n_settle), fys])
    packed = par.pack(**ov)
    if not pid_on:
        from .params import P_PID_ON

        packed[P_PID_ON] = 0.0
    if clamp_m is not None:
        from .params import P_CLAMP, P_CLAMP_X, P_CLAMP_Y

        packed[P_CLAMP] = 1.0
        packed[P_CLAMP_X], packed[P_CLAMP_Y] = float(clamp_m[0]), float(clamp_m[1])
    nx, nym, ni = noise_arrays(noise, n_tot)
    # equilibrium for the static part of the load at t = 0 (the pre-roll settles the rest)
    eq = equilibrium(par, packed, f_x_n=float(f_x[0]), f_y_n=float(f_y[0]))
    calib = None
    if cfg["selfsensing"]["calibrate"]:
        calib = calibrate_selfsensing(par, par.pack(**{k: v for k, v in ov.items() if k in ("XCOUP", "DEADTIME")}),
                                      cfg["selfsensing"]["calibration_positions_m"])
        from .params import P_SS_GAIN, P_SS_OFF

        packed[P_SS_GAIN] = calib["gain"]
        packed[P_SS_OFF] = calib["offset_m"]
    if progress is None:
        progress = dur >= 1.0
    out, fine, rip, st = _run(par, packed, exp["start"], eq,
                              padded(sig["r_x"]), padded(sig["r_y"]), padded(sig["inj_x"], 0.0),
                              padded(sig["inj_y"], 0.0), f_x, f_y, nx, nym, ni,
                              record_fine=record_fine, progress=progress, track_ripple=track_ripple,
                              desc=f"simulate {experiment or ''}".strip())
    sl = slice(n_settle, n_tot)
    data = {name: out[i, sl] for i, name in enumerate(OUT_NAMES)}   # views, no copies
    data["t"] = data["t"] - settle
    data["r_x"] = sig["r_x"]
    data["r_y"] = sig["r_y"]
    data["inj_x"] = sig["inj_x"]
    data["inj_y"] = sig["inj_y"]
    data["f_ext_x_n"] = f_x[sl]
    data["f_ext_y_n"] = f_y[sl]
    data["fs_hz"] = np.asarray(fs)
    ripple = {"t": rip[0] - settle, "i_max": rip[1], "i_min": rip[2]}
    ripple_keep = ripple["t"] >= 0
    ripple = {k: v[ripple_keep] for k, v in ripple.items()}
    fine_d = None
    if record_fine:
        fsl = slice(n_settle * par.substeps, n_tot * par.substeps)
        fine_d = {"t": fine[0, fsl] - settle}
        for j, cname in enumerate(COILS):
            fine_d["i_" + cname] = fine[1 + j, fsl]
            fine_d["phi_" + cname] = fine[5 + j, fsl]
            fine_d["v_" + cname] = fine[9 + j, fsl]
    wall = time.perf_counter() - t_wall
    meta = {
        "kind": "simulation",
        "experiment": experiment,
        "excitation": {**dict(exc), **info},
        "force_excitation": force_info,
        "start": exp["start"],
        "duration_s": dur,
        "fs_hz": fs,
        "seed": seed,
        "settle_s": settle,
        "substeps": par.substeps,
        "effects": [dict(e) for e in effects],
        "noise": dict(noise) if noise else None,
        "selfsensing_calibration": calib,
        "equilibrium": {"u_x": eq["u_x"], "u_y": eq["u_y"], "currents_a": eq["currents_a"].tolist()},
        "delevitation_s": delevitation_time(data["t"], data["contact"], exp["start"]),
        "config_hash": config_hash(cfg),
        "wall_time_s": wall,
        "coils": list(COILS),
    }
    return SimResult(data=data, meta=meta, ripple=ripple, fine=fine_d)
