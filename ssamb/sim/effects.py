"""The effect library: physical effects a rig may have and the nominal model lacks.

Each effect maps to kernel parameters or to the external-force arrays, so adding one is a
local change: a validator here, and either a kernel parameter (``params.P_*``) or a force
time series. Names and parameters follow ARCHITECTURE.md:

==================== =========================================== ======================================
name                 parameters                                  acts on
==================== =========================================== ======================================
sensor_delay         axis (x, y, both), delay_s                  transport delay of the position fed to
                                                                 the controller (x probe; y: the DCM
                                                                 estimate), fractional samples
unbalance            speed_hz, mass_ecc_kgm, [phase_rad]         rotating force m e w^2 (cos, sin)
static_load          fx_n, fy_n                                  constant external force
sensor_gain          axis, gain                                  scale error of the position measurement
amplifier_deadtime   deadtime_s                                  turn-on delay of every PWM pulse
cross_coupling       coefficient                                 extra flux shared between adjacent magnets
                                                                 (on top of the stator network's, forces)
external_force       file (CSV: t, fx_n, fy_n) or t/fx_n/fy_n    arbitrary force, linear interpolation
==================== =========================================== ======================================
"""
from __future__ import annotations

import math
import numbers
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from ..errors import InputError

__all__ = ["EFFECTS", "EffectError", "validate_effect", "apply_effects"]


class EffectError(InputError):
    """An effect specification is invalid; the message names the effect and the parameter."""


#: name -> (required parameters, optional parameters)
EFFECTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "sensor_delay": (("axis", "delay_s"), ()),
    "unbalance": (("speed_hz", "mass_ecc_kgm"), ("phase_rad",)),
    "static_load": (("fx_n", "fy_n"), ()),
    "sensor_gain": (("axis", "gain"), ()),
    "amplifier_deadtime": (("deadtime_s",), ()),
    "cross_coupling": (("coefficient",), ()),
    "external_force": ((), ("file", "t", "fx_n", "fy_n")),
}


def validate_effect(effect: Mapping) -> dict:
    """Check one effect ``{name: ..., <params>}`` (or ``{name:, params: {...}}``); return a flat dict."""
    if "name" not in effect:
        raise EffectError(f"effect {dict(effect)!r}: missing 'name'")
    name = effect["name"]
    if name not in EFFECTS:
        raise EffectError(f"effect '{name}': unknown (known: {', '.join(EFFECTS)})")
    flat = dict(effect.get("params", {}))
    flat.update({k: v for k, v in effect.items() if k not in ("name", "params")})
    req, opt = EFFECTS[name]
    for k in req:
        if k not in flat:
            raise EffectError(f"effect '{name}': missing parameter '{k}'")
    for k in flat:
        if k not in req and k not in opt:
            raise EffectError(f"effect '{name}': unknown parameter '{k}' (allowed: {', '.join(req + opt)})")
    for k, v in flat.items():
        _check_type(name, k, v)
    if "axis" in flat and flat["axis"] not in ("x", "y", "both"):
        raise EffectError(f"effect '{name}': axis must be x, y or both (got {flat['axis']!r})")
    if name == "sensor_delay" and not 0 <= float(flat["delay_s"]) < 2.5e-3:
        raise EffectError(f"effect 'sensor_delay': delay_s must be in [0, 2.5e-3) s (got {flat['delay_s']})")
    if name == "sensor_gain" and not float(flat["gain"]) > 0:
        raise EffectError(f"effect 'sensor_gain': gain must be > 0 (got {flat['gain']})")
    if name == "amplifier_deadtime" and not 0 <= float(flat["deadtime_s"]) < 1e-5:
        raise EffectError(f"effect 'amplifier_deadtime': deadtime_s must be in [0, 10 us) (got {flat['deadtime_s']})")
    if name == "unbalance" and (float(flat["speed_hz"]) < 0 or float(flat["mass_ecc_kgm"]) < 0):
        raise EffectError("effect 'unbalance': speed_hz and mass_ecc_kgm must be >= 0")
    if name == "external_force" and "file" not in flat and not all(k in flat for k in ("t", "fx_n", "fy_n")):
        raise EffectError("effect 'external_force': give 'file' (CSV with t, fx_n, fy_n) or arrays t, fx_n, fy_n")
    return {"name": name, **flat}


def _check_type(name: str, key: str, value) -> None:
    """Every parameter is one finite real number, except ``axis`` and ``file`` (text) and the
    ``external_force`` arrays ``t``, ``fx_n``, ``fy_n`` (non-empty lists of finite numbers)."""
    if key in ("axis", "file"):
        ok, kind = isinstance(value, str), "text"
    elif name == "external_force":
        try:
            arr = np.asarray(value) if isinstance(value, (list, tuple, np.ndarray)) else np.empty((0, 0))
        except ValueError:        # ragged
            arr = np.empty((0, 0))
        ok = (arr.ndim == 1 and arr.size > 0 and arr.dtype.kind in "iuf" and bool(np.isfinite(arr).all()))
        kind = "a list of finite numbers"
    else:
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(float(value))
        kind = "a finite number"
    if not ok:
        raise EffectError(f"effect '{name}': parameter '{key}' must be {kind} (got {value!r})")


def _axes(axis: str) -> tuple[str, ...]:
    return ("x", "y") if axis == "both" else (axis,)


def apply_effects(effects: Iterable[Mapping], t: np.ndarray, base_dir: str | Path | None = None):
    """Translate effects into kernel-parameter overrides and external-force arrays.

    Parameters
    ----------
    effects : iterable of mappings
        Effect specifications (see module table).
    t : array
        Sample times (s) at which the external force is evaluated (held over each sample).

    Returns
    -------
    overrides : dict
        Kernel parameter overrides (``DELAY_X``, ``GAIN_Y``, ...); effects of the same kind add
        (delays, forces) or multiply (gains).
    f_x, f_y : arrays
        External force (N) on the rotor at every sample.
    """
    ov: dict[str, float] = {}
    f_x = np.zeros_like(t, dtype=float)
    f_y = np.zeros_like(t, dtype=float)
    for raw in effects:
        e = validate_effect(raw)
        name = e["name"]
        if name == "sensor_delay":
            for ax in _axes(e["axis"]):
                key = "DELAY_" + ax.upper()
                ov[key] = ov.get(key, 0.0) + float(e["delay_s"])
        elif name == "sensor_gain":
            for ax in _axes(e["axis"]):
                key = "GAIN_" + ax.upper()
                ov[key] = ov.get(key, 1.0) * float(e["gain"])
        elif name == "amplifier_deadtime":
            ov["DEADTIME"] = ov.get("DEADTIME", 0.0) + float(e["deadtime_s"])
        elif name == "cross_coupling":
            ov["XCOUP"] = ov.get("XCOUP", 0.0) + float(e["coefficient"])
        elif name == "static_load":
            f_x += float(e["fx_n"])
            f_y += float(e["fy_n"])
        elif name == "unbalance":
            w = 2 * math.pi * float(e["speed_hz"])
            amp = float(e["mass_ecc_kgm"]) * w * w
            ph = float(e.get("phase_rad", 0.0))
            f_x += amp * np.cos(w * t + ph)
            f_y += amp * np.sin(w * t + ph)
        elif name == "external_force":
            if "file" in e:
                path = Path(e["file"])
                if not path.is_absolute() and base_dir is not None:
                    path = Path(base_dir) / path
                if not path.exists():
                    raise EffectError(f"effect 'external_force': file '{path}' not found")
                tab = np.genfromtxt(path, delimiter=",", names=True)
                missing = [c for c in ("t", "fx_n", "fy_n") if c not in (tab.dtype.names or ())]
                if missing:
                    raise EffectError(f"effect 'external_force': file '{path}' lacks column(s) {', '.join(missing)}")
                te, fxe, fye = tab["t"], tab["fx_n"], tab["fy_n"]
            else:
                te, fxe, fye = (np.asarray(e[k], float) for k in ("t", "fx_n", "fy_n"))
            f_x += np.interp(t, te, fxe)
            f_y += np.interp(t, te, fye)
    return ov, f_x, f_y
