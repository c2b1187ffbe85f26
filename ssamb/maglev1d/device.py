r"""The levitated ball as a :class:`ssamb.device.Device` of close the loop.

Data: the rig logs ``y`` (m), ``i`` (A), ``u`` (V) and the reference ``yd`` (m) at 100 Hz
(:mod:`.data`). A record's usable part is its levitated stretches (:mod:`.data`: the ball away
from both stops by ``levitation.margin_m`` with the coil carrying at least
``levitation.min_current_a``, for at least ``levitation.min_duration_s``), less their first
``levitation.settle_s``. The rest -- the ball held by hand before the controller takes it, resting
on the lower stop, stuck to the magnet, falling between them -- is left out: the model has the
stops, but a drop or a stick is a threshold event whose timing no replay reproduces sample by
sample.

Replay: each levitated stretch is replayed from its first sample on, from the state the record
gives there: the measured position (through the sensor model's inverse), its velocity from a
local quadratic fit, the measured current, and the controller's exact internal state (the
controller is run over the whole log, :mod:`.controller`; it reproduces the logged command, so
its integrators are known). Outside the stretches the replay returns the record's own samples.
The reference ``yd`` drives the replay. A replay is a realisation of the noise (:mod:`.physics`:
sensor noise before the ADCs, a random force), drawn from ``seed`` in the replays' own noise stream
(:data:`REPLAY_STREAM`: a simulated rig's log draws from another); ``seed=None`` replays without
noise. It is deterministic given (config, effects, seed), and the device object pickles.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from ..device import REPLAY_STREAM, Device, FeatureSpec, Record, Replay
from ..io import DataError
from . import config as _config
from . import controller as _ctl
from . import physics as _phys
from .data import (COLUMNS, levitated_mask, levitated_stretches, load_data, validate_arrays)

__all__ = ["Maglev1D", "one_level_family"]


def one_level_family(a_m: float, k_h: float, gain: float, new_gain: float, level_m: float) -> tuple:
    r"""The force law's length and constant :math:`(a', k')` that, with the position sensor's
    scale ``new_gain`` instead of ``gain`` (its zero at the magnet's face), leave the equilibrium
    current :math:`\sqrt{2mg/(ka)}\,(a + Y/g_s)` and the gap-dependent inductance
    :math:`ka/(a + Y/g_s)` at the reading ``level_m`` :math:`Y` unchanged: :math:`a' + Y/g' = a + Y/g_s`,
    :math:`k'a' = ka`.

    Examples
    --------
    >>> a2, k2 = one_level_family(0.005, 0.03, 1.0, 0.8, 0.005)
    >>> round(a2 + 0.005 / 0.8, 12), round(k2 * a2, 12)
    (0.01, 0.00015)
    """
    a2 = a_m + level_m / gain - level_m / new_gain
    return a2, k_h * a_m / a2


#: the noise stream of a rig's own log (:meth:`Maglev1D.simulate_log`, :meth:`Maglev1D.rig_log`);
#: the model's replays of a record draw from :data:`ssamb.device.REPLAY_STREAM`
RIG_STREAM = 0


def _draws(seed: int | None, n: int, additive: bool, stream: int = REPLAY_STREAM) -> tuple:
    """A replay's random draws from the noise stream ``stream``: ``(3, n)`` standard normal
    (position, current, force noise) and, with additive quantisers, ``(3, n)`` uniform on
    :math:`[-1/2, 1/2)` (the position and current ADCs' and the PWM's rounding errors) from a
    stream of their own (a replay's first samples do not depend on its length); None for
    ``seed=None`` (no noise; the rounding errors at their mean)."""
    if seed is None:
        return None, None
    memo = (int(seed), int(n), bool(additive), int(stream))
    hit = _DRAWS.pop(memo, None)
    if hit is None:
        key = [int(seed)] if stream == RIG_STREAM else [int(seed), int(stream)]
        noise = np.ascontiguousarray(np.random.default_rng(key).standard_normal((n, 3)).T)
        dither = np.ascontiguousarray(np.random.default_rng([*key, 1]).random((n, 3)).T - 0.5) if additive else None
        hit = (noise, dither)
    _DRAWS[memo] = hit                  # most recently used last
    while len(_DRAWS) > _DRAWS_KEPT:
        _DRAWS.pop(next(iter(_DRAWS)))
    return hit


#: the draws of recent replays (a fit replays every parameter set with the same seeds), shared
#: between the replays that ask for them: the kernel only reads them
_DRAWS: dict = {}
_DRAWS_KEPT = 64


def _chk_face(record: Record, cfg: Mapping) -> dict:
    """:func:`ssamb.maglev1d.checks.face_reading` of a record."""
    from .checks import face_reading

    return face_reading({**record.channels, "yd": record.inputs["yd"]}, cfg)


class Maglev1D(Device):
    """The 1-DOF levitated steel ball (module docstring)."""

    name = "maglev1d"
    channels = ("y", "i", "u")
    view_names = ("y", "i", "u")
    cost_views = ("y", "i", "u")
    units = {"y": "m", "i": "A", "u": "V", "yd": "m"}
    error_groups = {}
    features = FeatureSpec(
        paths={"y/i": ("y", "y", "i"), "i/u": ("y", "i", "u")},
        axis_views={"y": ("y", "i", "u")},
        counterpart={},
        line_views=("y", "i", "u"),
        ripple_views=(),
        band_views=("y", "i", "u"),
    )
    effects_package = "ssamb.maglev1d.effects"

    # -- configuration
    def default_config(self) -> dict:
        return _config.load_config()

    def load_config(self, path=None) -> dict:
        return _config.load_config(path)

    def priors(self, cfg: Mapping) -> dict:
        return dict((cfg.get("closeloop") or {}).get("calibration") or {})

    def floors(self, settings) -> dict:
        """One ADC count over :math:`\\sqrt{12}` for ``y`` and ``i`` (at least the settings'
        floors), and for ``u`` one PWM step over :math:`\\sqrt{12}` (the command's resolution at
        the coil)."""
        cfg = self.default_config()
        qy, qi = _ctl.position_lsb_m(cfg), _ctl.current_lsb_a(cfg)
        pwm = cfg["controller"]["v_ref_v"] / cfg["amplifier"]["pwm_steps"]
        r12 = np.sqrt(12.0)
        return {"y": max(qy / r12, float(getattr(settings, "floor_position_m", 0.0))),
                "i": max(qi / r12, float(getattr(settings, "floor_current_a", 0.0))),
                "u": pwm / r12}

    def initial_estimate(self, record: Record, cfg: Mapping) -> dict:
        """A start for the calibration (optional, beyond :class:`ssamb.device.Device`): dotted config
        key -> value that the data imply by the physical checks (:func:`ssamb.maglev1d.checks.start_estimate`),
        each kept within five tolerances of its nominal value. The published-parameter model's loop
        is unstable on this rig (its replays drop the ball), so a calibration that starts there
        sees no gradient."""
        from .checks import start_estimate

        arrays = {**record.channels, "yd": record.inputs["yd"]}
        est = start_estimate(arrays, cfg)
        gk = "sensors.position_gain"
        if gk not in est and gk in self.priors(cfg) and {"magnet.k_h", "magnet.a_m"} & set(self.priors(cfg)):
            est = self._levitating_gain(record, cfg, est)
        out = {}
        for key, val in est.items():
            tol = self.priors(cfg).get(key)
            if tol is None:
                continue
            nom = float(_config.get(cfg, key))
            span = 5 * tol * (abs(nom) if nom != 0 else 1.0)
            out[key] = float(np.clip(val, nom - span, nom + span))
        return out

    def _levitating_gain(self, record: Record, cfg: Mapping, est: Mapping, seeds: int = 4) -> dict:
        r"""The start's sensor scale where the data do not determine it (no settled plateaus at two
        levels: :func:`ssamb.maglev1d.checks.start_estimate` leaves it at its nominal value).

        At one reading level :math:`Y` (the zero at the face, :math:`o_s = 0`) the equilibrium
        current :math:`(C/g_s)(a g_s + Y)`, :math:`C = \sqrt{2mg/(ka)}`, and the inductance
        :math:`k a g_s/(a g_s + Y)` stay as they are for another scale :math:`g'` with
        :math:`a' = a + Y/g_s - Y/g'` and :math:`k' a' = k a`: the data at one level cannot tell
        these models apart, but their loops differ, and the rig's ball floated. The start is the
        member nearest the nominal scale (steps of half its tolerance, up to two tolerances) whose
        replays with ``seeds`` seeds keep the ball off the stops (fewest drops when none does).
        """
        from ..config import apply_overrides

        g0 = float(cfg["sensors"]["position_gain"])
        tol = float(self.priors(cfg)["sensors.position_gain"])
        a = float(est.get("magnet.a_m", cfg["magnet"]["a_m"]))
        k = float(est.get("magnet.k_h", cfg["magnet"]["k_h"]))
        o = float(est.get("sensors.position_offset_m", cfg["sensors"]["position_offset_m"]))
        lev = np.concatenate([record.channels["y"][s:e] for s, e in record.usable]) if record.usable else None
        if lev is None or not len(lev):
            return dict(est)
        y_read = float(np.mean(lev)) - o                   # the level, from the face
        best, fewest = dict(est), None
        for step in (0.0, -0.5, 0.5, -1.0, 1.0, -1.5, 1.5, -2.0, 2.0):
            g = g0 * (1.0 + step * tol)
            if g <= 0:
                continue
            a2, k2 = one_level_family(a, k, g0, g, y_read)
            if a2 <= 0:
                continue
            cand = dict(est) if step == 0.0 else {**est, "sensors.position_gain": g, "magnet.a_m": a2,
                                                  "magnet.k_h": k2}
            c = apply_overrides(cfg, cand)
            if self.physical(c):
                continue
            drops = sum(bool(self.replay(c, record, [], record.n, 9_000 + j).contact) for j in range(seeds))
            if fewest is None or drops < fewest:
                best, fewest = cand, drops
            if drops == 0:
                break
        return best

    def start_candidates(self, record: Record, cfg: Mapping, start: Mapping) -> list:
        r"""Other starts for the calibration about ``start`` (dotted key -> value; optional, beyond
        :class:`ssamb.device.Device`): the members of the one-level family
        (:func:`one_level_family`) through it at the mean reading of the compared parts, the sensor's
        scale moved in steps of a quarter of its tolerance up to two tolerances. At one level the
        data's equilibrium current and inductance cannot tell them apart, but their loops, and so
        the replays' spectra, differ; the calibration starts from the one that fits the fitting part
        best (:func:`ssamb.closeloop.calibration.calibrate_model`). None where the start lacks the
        scale, the law's length or its constant."""
        keys = ("sensors.position_gain", "magnet.a_m", "magnet.k_h")
        pri = self.priors(cfg)
        if not all(k in start and k in pri for k in keys) or not record.usable:
            return []
        g0, a, k = (float(start[x]) for x in keys)
        o = float(start.get("sensors.position_offset_m", cfg["sensors"]["position_offset_m"]))
        lev = np.concatenate([record.channels["y"][s:e] for s, e in record.usable])
        y_read = float(np.mean(lev)) - o
        tol = float(pri["sensors.position_gain"]) * float(cfg["sensors"]["position_gain"])
        out = []
        for step in np.arange(-2.0, 2.0 + 1e-9, 0.25):
            g = g0 + step * tol
            if step == 0 or g <= 0:
                continue
            a2, k2 = one_level_family(a, k, g0, g, y_read)
            if a2 > 0 and k2 > 0:
                out.append({**start, "sensors.position_gain": g, "magnet.a_m": a2, "magnet.k_h": k2})
        return out

    def calibration_bounds(self, record: Record, cfg: Mapping) -> dict:
        r"""The position sensor's zero :math:`o_s` is the reading of the ball at the magnet's face
        (:mod:`.physics`: reading :math:`g_s y + o_s`, the face at :math:`y = 0`), so a model whose
        :math:`o_s` lies above a reading the levitated ball gave puts the face inside the range it
        floated in. Upper limit: the lowest reading of the compared parts, or the reading of the
        ball held at the face where the recording shows one (clipped at the ADC's 0: the zero lies
        at or below it), each plus three standard deviations of a reading (its noise and its
        rounding)."""
        y = record.channels["y"]
        lows = [float(np.min(y[a:b])) for a, b in record.usable]
        f = _chk_face(record, cfg)
        if f["samples"]:
            lows.append(float(f["reading_m"]))
        if not lows:
            return {}
        qy = _ctl.position_lsb_m(cfg)
        sd = float(np.hypot(cfg["noise"]["position_m"], qy / np.sqrt(12.0)))
        return {"sensors.position_offset_m": (None, min(lows) + 3 * sd)}

    def checks(self, arrays: Mapping, cfg: Mapping) -> dict:
        """Physical checks of the model with ``cfg`` against one recording (:mod:`.checks`), each with a
        one-line ``summary``: the coil's time constant, the command's incremental resistance and
        offset (the current's response to the command), the equilibrium current on settled plateaus
        against the force law, the linearised loop at the reference's levels and at the lowest reading
        of the compared parts (0.5 % quantile; the rig levitates there), the current reading with the stage
        off, the position reading of the ball held at the magnet's face, and whether the logged command
        follows from the logged signals."""
        from . import checks as _chk

        from .physics import equilibrium_current_a, inductance_h

        c = _chk.coil_time_constant(arrays, cfg)
        p = _phys.knobs_of(cfg)
        b, mg = cfg["ball"], cfg["magnet"]
        r_tot = cfg["coil"]["r_ohm"] + cfg["coil"]["r_shunt_ohm"]
        tau_model = float(inductance_h(_phys.position_m(p, c["y_mean_m"]), mg["k0_h"], mg["k_h"], mg["a_m"])) / r_tot
        gain = cfg["amplifier"]["v_max_v"] / cfg["controller"]["v_ref_v"]
        out = {"coil_time_constant": {"measured_s": c["tau_s"], "model_s": tau_model, "samples": c["samples"],
                                      "y_mean_m": c["y_mean_m"],
                                      "summary": f"L/R {1e3 * c['tau_s']:.1f} ms from the current's response to the "
                                                 f"command, model {1e3 * tau_model:.1f} ms"},
               "command_per_current": {"measured_ohm": c["r_over_gain_ohm"], "model_ohm": r_tot / gain,
                                       "summary": f"command per ampere {c['r_over_gain_ohm']:.2f} ohm, model "
                                                  f"{r_tot / gain:.2f} ohm (R V_ref/V_max)"},
               "command_offset": {"measured_v": c["offset_v"],
                                  "model_v": cfg["amplifier"]["drop_v"] / gain,
                                  "summary": f"command at zero current {c['offset_v']:.2f} V, model "
                                             f"{cfg['amplifier']['drop_v'] / gain:.2f} V (the stage's drop)"}}
        e = _chk.equilibrium_currents(arrays, cfg)
        if e["plateaus"]:
            ym = _phys.position_m(p, np.array(e["y_m"]))
            pred = equilibrium_current_a(ym, b["mass_kg"], b["gravity_m_per_s2"], mg["k_h"], mg["a_m"])
            ratio = np.array(e["i_a"]) / pred
            out["equilibrium_current"] = {"plateaus": e["plateaus"], "measured_a": float(np.mean(e["i_a"])),
                                          "model_a": float(np.mean(pred)),
                                          "ratio_min": float(np.min(ratio)), "ratio_max": float(np.max(ratio)),
                                          "summary": f"{e['plateaus']} settled plateaus: measured current "
                                                     f"{np.min(ratio):.3f}-{np.max(ratio):.3f} times the force law's"}
        levels = np.unique(np.round(np.asarray(arrays["yd"], float), 5))
        levels = levels if len(levels) <= 5 else np.quantile(np.asarray(arrays["yd"], float), [0.1, 0.5, 0.9])
        lev = np.zeros(len(arrays["y"]), bool)
        for a, b in self.usable_parts(arrays, cfg, self.stretches(arrays, cfg)):
            lev[a:b] = True
        low = float(np.quantile(np.asarray(arrays["y"], float)[lev], 0.005)) if lev.any() else None
        if low is not None and low < float(np.min(levels)) - 5e-4:
            levels = np.r_[np.round(low, 5), levels]
        st = self.stable_at(cfg, levels)
        stable = all(r["stable"] for r in st.values())
        bad = [v for v, r in st.items() if not r["stable"]]
        out["linearised_loop"] = {"levels_m": [float(v) for v in st],
                                  "spectral_radius": [r["spectral_radius"] for r in st.values()],
                                  "least_damping": [r["least_damping"] for r in st.values()],
                                  "model_stable": stable, "rig_levitates": True,
                                  "summary": f"the rig levitates at {', '.join(f'{1e3 * v:.2f}' for v in st)} mm (the "
                                             f"references and the lowest reading it recovers from); the model's "
                                             f"linearised loop is "
                                             + ("stable there" if stable else
                                                f"UNSTABLE at {', '.join(f'{1e3 * v:.2f}' for v in bad)} mm")
                                             + f" (largest spectral radius "
                                               f"{max(r['spectral_radius'] for r in st.values()):.3f})"}
        r = _chk.current_at_rest(arrays, cfg)
        if r["samples"]:
            model_i = float(self.knobs(cfg, [])["current_offset_a"])
            out["current_at_rest"] = {**r, "model_a": model_i,
                                      "summary": f"current reading after 0.2 s of zero command "
                                                 f"{1e3 * r['current_a']:.1f} mA "
                                                 f"({r['samples']} samples), model {1e3 * model_i:.1f} mA"}
        f = _chk.face_reading(arrays, cfg)
        if f["samples"]:
            model_r = float(_phys.reading_m(p, 0.0))
            out["face_reading"] = {**f, "model_m": model_r,
                                   "summary": f"ball held at the magnet's face reads {1e3 * f['reading_m']:.2f} mm"
                                              f"{' (the ADC clips at 0)' if f['clipped'] else ''} "
                                              f"({f['samples']} samples), model {1e3 * model_r:.2f} mm"}
        k = _ctl.check(arrays, cfg)
        out["controller"] = {**k, "summary": f"the logged command follows from the logged signals through the rig's "
                                             f"controller in {100 * k['within_rounding']:.0f} % of samples within the "
                                             f"log's rounding, {100 * k['within_pwm_step']:.0f} % within one PWM step"}
        return out

    # -- data
    def load(self, path) -> tuple[dict, dict]:
        return load_data(path)

    def validate(self, arrays: Mapping, source: str) -> None:
        """Shapes, values, the time base, and that the ball levitates somewhere in the log."""
        cfg = self.default_config()
        validate_arrays(arrays, source, float(cfg["controller"]["ts_s"]))
        if not self.stretches(arrays, cfg):
            lev, st = cfg["levitation"], cfg["stops"]
            y = np.asarray(arrays["y"], float)
            hint = ""
            if np.max(np.abs(y)) > 10 * st["bottom_m"]:
                hint = f"; its values reach {np.max(np.abs(y)):.4g}: in mm? this device reads metres"
            elif np.max(np.abs(arrays["i"])) > 100:
                hint = f"; the current reaches {np.max(np.abs(arrays['i'])):.4g}: in mA? this device reads amperes"
            raise DataError(f"{source}: column 'y': the ball never levitates "
                            f"(no stretch of {lev['min_duration_s']:g} s "
                            f"with y between {1e3 * (st['top_m'] + lev['margin_m']):.3g} and "
                            f"{1e3 * (st['bottom_m'] - lev['margin_m']):.3g} mm "
                            f"and i >= {lev['min_current_a']:g} A){hint}")

    def stretches(self, arrays: Mapping, cfg: Mapping) -> list[tuple[int, int]]:
        """The levitated stretches ``[a, b)`` of a log (:mod:`.data`)."""
        lev, st = cfg["levitation"], cfg["stops"]
        m = levitated_mask(arrays["y"], arrays["i"], st["top_m"], st["bottom_m"], lev["margin_m"], lev["min_current_a"])
        return levitated_stretches(m, int(round(lev["min_duration_s"] / cfg["controller"]["ts_s"])))

    def usable_parts(self, arrays: Mapping, cfg: Mapping, stretches) -> tuple:
        """The compared parts of the levitated stretches: each from ``levitation.settle_s`` after
        the controller has caught the ball (its first sample within ``levitation.capture_m`` of
        the reference) until the ball escapes it (more than ``levitation.lost_m`` from the
        reference: the demand's proportional part alone then drives the current to its limit),
        at least ``levitation.min_usable_s`` long; a stretch can hold several. Left out: the lift-off
        or recovery through the large gaps, and an escape, threshold events whose timing no
        replay reproduces from a known state."""
        ts = float(cfg["controller"]["ts_s"])
        lev = cfg["levitation"]
        settle = int(round(lev["settle_s"] / ts))
        shortest = int(round(lev["min_usable_s"] / ts))
        dev = np.abs(np.asarray(arrays["y"], float) - np.asarray(arrays["yd"], float))
        out = []
        for a, b in stretches:
            k = a
            while k < b:
                hit = np.nonzero(dev[k:b] <= lev["capture_m"])[0]
                if not len(hit):
                    break
                s0 = k + int(hit[0]) + settle
                lost = np.nonzero(dev[s0:b] > lev["lost_m"])[0] if s0 < b else np.array([], int)
                e = s0 + int(lost[0]) if len(lost) else b
                if e - s0 >= shortest:
                    out.append((int(s0), int(e)))
                k = max(e, k + 1)
        return tuple(out)

    def notes(self, arrays: Mapping, meta: Mapping, cfg: Mapping) -> list[str]:
        """Valid but suspicious data: units off by 1000, channels that never move, a reference
        outside the sensor's range, a command beyond the controller's limits, values off the
        ADC grids (not the rig's own logs, or rescaled)."""
        out = []
        y, i, u, yd = (np.asarray(arrays[c], float) for c in ("y", "i", "u", "yd"))
        qy, qi = _ctl.position_lsb_m(cfg), _ctl.current_lsb_a(cfg)
        if np.median(np.abs(yd)) > 1.0:
            out.append(f"yd: median {np.median(np.abs(yd)):.4g}: in mm? this device reads metres")
        if np.max(np.abs(i)) > 20 * cfg["controller"]["i_ref_a"]:
            out.append(f"i: up to {np.max(np.abs(i)):.4g} A, far beyond the current limit: in mA?")
        if np.max(u) > 1.001 * cfg["controller"]["v_ref_v"] or np.min(u) < -1e-9:
            out.append(f"u: {np.min(u):.4g} .. {np.max(u):.4g} V lies outside the controller's range "
                       f"[0, {cfg['controller']['v_ref_v']:g}] V")
        for c, a in (("y", y), ("i", i), ("u", u)):
            if np.ptp(a) == 0:
                out.append(f"{c}: constant ({a[0]:.4g}): the channel never moves")
        for c, a, q in (("y", y, qy), ("i", i, qi)):
            off = np.abs(a / q - np.round(a / q))
            if np.median(off) > 0.05:
                out.append(f"{c}: values are not whole ADC counts ({q:.4g} per count): "
                           f"filtered, rescaled, or another rig")
        lev = np.zeros(len(y), bool)
        for a, b in self.stretches(arrays, cfg):
            lev[a:b] = True
        if lev.any():
            u_ctl, _ = _ctl.run(qy * np.round(y / qy), qi * np.round(i / qi), yd, _ctl.gains_of(cfg))
            pwm = cfg["controller"]["v_ref_v"] / cfg["amplifier"]["pwm_steps"]
            share = float(np.mean(np.abs(u_ctl - u)[lev] <= pwm))
            if share < 0.9:
                out.append(f"u: the logged command follows from the logged y, i, yd through the rig's controller "
                           f"in only {100 * share:.0f} % of the levitated samples (within one PWM step): "
                           f"another controller, "
                           f"a reference other than the logged yd, rounded signals, or a spliced log; the replay runs "
                           f"the rig's controller on the logged yd")
        return out

    def record(self, arrays: Mapping, meta: Mapping, cfg: Mapping, source: str) -> Record:
        """The record: channels, the reference as input, the usable stretches, replay starts."""
        arr = {c: np.ascontiguousarray(np.asarray(arrays[c], float)) for c in COLUMNS}
        ts = float(cfg["controller"]["ts_s"])
        stretches = self.stretches(arr, cfg)
        if not stretches:
            raise DataError(f"{source}: column 'y': the ball never levitates")
        usable = self.usable_parts(arr, cfg, stretches)
        if not usable:
            lev = cfg["levitation"]
            raise DataError(f"{source}: column 'y': the ball levitates but never stays within "
                            f"{1e3 * lev['lost_m']:g} mm of the reference 'yd' "
                            f"for {lev['settle_s'] + lev['min_usable_s']:g} s after coming within "
                            f"{1e3 * lev['capture_m']:g} mm of it: nothing to compare")
        qy, qi = _ctl.position_lsb_m(cfg), _ctl.current_lsb_a(cfg)
        # the controller's state before every sample, from the log itself (it saw whole counts)
        _, states = _ctl.run(qy * np.round(arr["y"] / qy), qi * np.round(arr["i"] / qi), arr["yd"],
                             _ctl.gains_of(cfg))
        yd = arr["yd"]
        varies = np.ptp(yd) > 0
        steps = np.count_nonzero(np.diff(yd))
        kind = "constant" if not varies else ("steps" if steps <= 20 else "varying")
        exc = {"kind": "reference", "profile": str(meta.get("profile", kind)), "shape": kind,
               "yd_min_m": float(np.min(yd)), "yd_max_m": float(np.max(yd))}
        n = len(yd)
        left = n - sum(b - a for a, b in usable)
        reason = (f"{left} of {n} samples left out: only the levitated stretches (ball away from both stops by "
                  f"{1e3 * cfg['levitation']['margin_m']:g} mm, "
                  f"coil current >= {cfg['levitation']['min_current_a']:g} A, "
                  f"for >= {cfg['levitation']['min_duration_s']:g} s) are compared, from "
                  f"{cfg['levitation']['settle_s']:g} s after the ball first comes within "
                  f"{1e3 * cfg['levitation']['capture_m']:g} mm of the reference until it strays "
                  f"{1e3 * cfg['levitation']['lost_m']:g} mm from it; the ball held, on a stop, lifting off or "
                  f"falling is not replayed") if left else ""
        m = dict(meta)
        b, mg = cfg["ball"], cfg["magnet"]
        gain = cfg["amplifier"]["v_max_v"] / cfg["controller"]["v_ref_v"]
        m.update({"stretches": [list(s) for s in stretches], "controller_states": states, "t0_s": float(arr["t"][0]),
                  "source": source,
                  "constants": {"weight_n": b["mass_kg"] * b["gravity_m_per_s2"], "a_m": mg["a_m"], "v_gain": gain,
                                "u_per_i_ohm": (cfg["coil"]["r_ohm"] + cfg["coil"]["r_shunt_ohm"]) / gain}})
        return Record(device=self, fs_hz=1.0 / ts, channels={c: arr[c] for c in self.channels}, inputs={"yd": yd},
                      excitation=exc, excited_axes=("y",) if varies else (), signal={"y": yd} if varies else {},
                      n_period=None, lines_hz=None, start="levitated" if stretches[0][0] == 0 else "held",
                      settle_s=float(cfg["levitation"]["settle_s"]), acquisition={}, device_lines_hz=(),
                      usable=usable, usable_reason=reason, meta=m)

    # -- replay
    def knobs(self, cfg: Mapping, effects: list) -> dict:
        """The effect knobs of the kernel (:data:`ssamb.maglev1d.physics.KNOBS`) for ``effects``."""
        kn = _phys.neutral_knobs()
        lib = self.effects
        for e in effects or []:
            e = self.validate_effect(e)
            lib[e["name"]].apply(kn, e, cfg)
        return kn

    def initial_states(self, record: Record, cfg: Mapping, kn: Mapping, segments) -> np.ndarray:
        """``(n_segments, 7)`` initial states of the replay (module docstring)."""
        y = record.channels["y"]
        i = record.channels["i"]
        u = record.channels["u"]
        ts = 1.0 / record.fs_hz
        states = record.meta["controller_states"]
        p = _phys.knobs_of(cfg, kn)
        out = np.zeros((len(segments), 7))
        for j, (a, b) in enumerate(segments):
            lo, hi = max(a - 3, 0), min(a + 4, len(y))
            tt = (np.arange(lo, hi) - a) * ts
            c = np.polyfit(tt, y[lo:hi], 2) if hi - lo >= 3 else np.array([0.0, 0.0, y[a]])
            y0 = float(_phys.position_m(p, y[a]))      # the sensor model's inverse
            v0 = c[1] / float(_phys.reading_slope(p, y0))
            i0 = max(i[a] - kn["current_offset_a"], 0.0)
            out[j] = [y0, v0, i0, states[a, 0], states[a, 1], states[a, 2], u[a - 1] if a > 0 else 0.0]
        return out

    def replay(self, cfg: Mapping, record: Record, effects: list, n: int, seed: int | None,
               stream: int = REPLAY_STREAM) -> Replay:
        """The model's ``y, i, u`` over the first ``n`` samples (module docstring); ``stream``:
        the noise stream (:data:`REPLAY_STREAM` for the model's replays, :data:`RIG_STREAM` for a
        simulated rig's own log)."""
        n = int(min(n, record.n)) if n is not None else record.n
        kn = self.knobs(cfg, effects)
        p = _phys.knobs_of(cfg, kn)
        segs = [(a, min(b, n)) for a, b in record.usable if a < n]
        init = self.initial_states(record, cfg, kn, segs)
        noise, dither = _draws(seed, n, p[_phys.knob_index("additive_quantisers")] > 0, stream)
        out = _phys.simulate(p, _ctl.gains_of(cfg), record.inputs["yd"][:n], segs, init, noise,
                             t0_s=record.meta.get("t0_s", 0.0), dither=dither)
        ch = {}
        for c in self.channels:
            a = record.channels[c][:n].copy()
            sim = out[c]
            ok = np.isfinite(sim)
            a[ok] = sim[ok]
            ch[c] = a
        contact = False
        for a, b in record.usable:
            if a < n and np.any(out["contact"][a:min(b, n)]):
                contact = True
        return Replay(channels=ch, contact=contact)

    def simulate_log(self, cfg: Mapping, yd, effects: list | None = None, seed: int | None = None) -> dict:
        """A synthetic rig log (optional, beyond :class:`ssamb.device.Device`): arrays ``t, y, i, u, yd``
        of the model with ``effects`` driven by the reference ``yd`` (100 Hz samples), the ball
        released at rest at the reference's first value with the equilibrium current and the
        controller's integrators at their equilibrium (:func:`ssamb.maglev1d.physics.equilibrium`).
        For the randomized suite and tests: a rig whose truth is known."""
        yd = np.asarray(yd, float)
        kn = self.knobs(cfg, effects or [])
        p = _phys.knobs_of(cfg, kn)
        p[_phys.knob_index("additive_quantisers")] = 0.0     # a rig rounds
        y0, i0, u0 = _phys.equilibrium(p, float(yd[0]))
        init = np.array([[y0, 0.0, i0, 0.0, -(i0 + kn["current_offset_a"]), u0, u0]])
        n = len(yd)
        noise, _ = _draws(seed, n, False, RIG_STREAM)
        out = _phys.simulate(p, _ctl.gains_of(cfg), yd, [(0, n)], init, noise)
        return {"t": np.arange(n) * float(cfg["controller"]["ts_s"]), "y": out["y"], "i": out["i"], "u": out["u"],
                "yd": yd.copy()}

    def rig_log(self, cfg: Mapping, record: Record, effects: list | None = None, seed: int | None = None) -> Replay:
        """A rig's own log on the reference of ``record`` (optional, beyond :class:`ssamb.device.Device`;
        for rigs drawn for the randomized suite and tests): the model ``cfg`` with ``effects`` replayed
        over each usable stretch, in time order, from the state the log *as simulated so far* gives at
        the stretch's start; outside the stretches the record's own samples.

        A replay (:meth:`replay`) starts a stretch from the log: the position, velocity and current
        read there and the controller's state before it, which :meth:`record` reconstructs by running
        the controller over the whole log (its integrators carry every earlier sample). A rig's log
        must be consistent with that reconstruction: the state a later stretch starts from follows
        from the earlier stretches *as this rig ran them*, not as the recording's rig did (started
        from the recording's state, a later stretch of the rig's log begins with a transient that its
        own model, replayed from that log, does not reproduce). The noise of a sample is the same in
        every stretch's replay (one ``seed``, the record's length), drawn from the rig's noise stream
        (:data:`RIG_STREAM`), never the model's replays'.
        """
        import dataclasses

        qy, qi = _ctl.position_lsb_m(cfg), _ctl.current_lsb_a(cfg)
        ch = {c: np.array(record.channels[c], float) for c in self.channels}
        contact = False
        for a, b in record.usable:
            _, states = _ctl.run(qy * np.round(ch["y"] / qy), qi * np.round(ch["i"] / qi), record.inputs["yd"],
                                 _ctl.gains_of(cfg))
            one = dataclasses.replace(record, channels={c: ch[c].copy() for c in self.channels}, usable=((a, b),),
                                      meta={**record.meta, "controller_states": states})
            out = self.replay(cfg, one, effects or [], record.n, seed, RIG_STREAM)
            for c in self.channels:
                ch[c][a:b] = out.channels[c][a:b]
            contact = contact or bool(out.contact)
        return Replay(channels=ch, contact=contact)

    def balanced(self, cfg: Mapping, record: Record, effects: list | None = None, span_s: float = 0.3) -> dict:
        r"""The force constant and the stage's full-scale voltage that put the model (``cfg`` with
        ``effects``) in the balance the record shows at the start of each usable part (optional,
        beyond :class:`ssamb.device.Device`; for rigs drawn for the randomized suite and tests).

        A levitated ball's log says two things at the start of every usable part, averaged over its
        first ``span_s``: the reading :math:`\bar y_s` holds the ball with the current reading
        :math:`\bar\imath` (the force balance) and that current takes the command :math:`\bar u`
        (the stage's balance). The model's equilibrium at :math:`\bar y_s`
        (:func:`ssamb.maglev1d.physics.equilibrium`, with the effects' knobs) gives
        :math:`i_{eq} \propto k^{-1/2}` (saturation aside) and :math:`u_{eq} \propto 1/V_{max}`, so

        .. math:: k \leftarrow k \exp\Big(2\,\overline{\ln\frac{i_{eq} + i_{off}}{\bar\imath}}\Big),
                  \qquad V_{max} \leftarrow V_{max} \exp\Big(\overline{\ln\frac{u_{eq}}{\bar u}}\Big)

        (means over the parts, :math:`i_{off}` a current-reading offset), iterated to a fixed point.
        A model drawn otherwise and started from the record's state (which a replay does) is off its
        balance by the difference: 10-25 % of the current for rigs within the priors, and the ball
        meets a stop within 0.1 s, before the loop has corrected it.

        Returns
        -------
        dict
            ``{"magnet.k_h": ..., "amplifier.v_max_v": ...}``: overrides of ``cfg``.
        """
        from ..config import apply_overrides

        kn = self.knobs(cfg, effects or [])
        w = max(int(round(span_s * record.fs_hz)), 1)
        ch = record.channels
        parts = [(a, min(b, a + w)) for a, b in record.usable]
        ys, ii, uu = ([float(np.mean(ch[c][a:b])) for a, b in parts] for c in ("y", "i", "u"))
        k, vm = float(cfg["magnet"]["k_h"]), float(cfg["amplifier"]["v_max_v"])
        ioff = _phys.knob_index("current_offset_a")
        for _ in range(50):
            p = _phys.knobs_of(apply_overrides(cfg, {"magnet.k_h": k, "amplifier.v_max_v": vm}), kn)
            eq = [_phys.equilibrium(p, y) for y in ys]
            li = float(np.mean([np.log((e[1] + p[ioff]) / i) for e, i in zip(eq, ii)]))
            lu = float(np.mean([np.log(e[2] / u) for e, u in zip(eq, uu)]))
            k, vm = k * math.exp(2.0 * li), vm * math.exp(lu)
            if abs(li) < 1e-9 and abs(lu) < 1e-9:
                break
        return {"magnet.k_h": k, "amplifier.v_max_v": vm}

    def stable_at(self, cfg: Mapping, levels_m, effects: list | None = None) -> dict:
        """The linearised sampled loop at reference readings ``levels_m`` (optional, beyond
        :class:`ssamb.device.Device`; :func:`ssamb.maglev1d.checks.loop_poles`, with the sensor's
        scale and zero and a static load): ``{level: check}``. A rig drawn for a test whose loop is
        unstable at its reference cannot levitate there."""
        from .checks import loop_poles

        kn = self.knobs(cfg, effects or [])
        p = _phys.knobs_of(cfg, kn)
        out = {}
        for lv in levels_m:
            y0 = float(_phys.position_m(p, float(lv)))
            out[float(lv)] = loop_poles(cfg, y0, {"sensor_gain": float(_phys.reading_slope(p, y0)),
                                                  "extra_force_n": kn["extra_force_n"]})
        return out

    def physical(self, cfg: Mapping) -> str | None:
        """The config's physical ranges (:func:`ssamb.maglev1d.config.validate`): the message of the
        first value outside them, or None."""
        from ..config import ConfigError
        from .config import validate

        try:
            validate(cfg)
        except ConfigError as exc:
            return str(exc)
        return None

    def measured_contact(self, record: Record, cfg: Mapping, settings) -> bool:
        """Whether the measured ball comes within a count of a stop in the usable part."""
        y = record.channels["y"]
        st = cfg["stops"]
        q = _ctl.position_lsb_m(cfg)
        for a, b in record.usable:
            if np.any(y[a:b] <= st["top_m"] + q) or np.any(y[a:b] >= st["bottom_m"] - q):
                return True
        return False
