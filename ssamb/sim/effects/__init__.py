"""The AMB's effect library: physical effects a rig may have and the nominal model lacks.

One module per effect (:data:`MODULES`: every module of this package); each holds the effect's
parameters and their validation, how it enters the simulator (:func:`apply_effects`:
kernel-parameter overrides or external-force arrays), the signature it leaves in the residual and
the evidence for it, its parameterisation for fitting and its entry in ``closeloop.json`` (the
interface: :class:`ssamb.device.EffectModule`).
Names and parameters:

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

from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from ...device import effect_modules
from ._common import EffectError, check_type

__all__ = ["MODULES", "EFFECTS", "EffectError", "validate_effect", "apply_effects"]

#: the effect modules (every module of this package), in the order close the loop ranks ties
MODULES = tuple(effect_modules(__name__))

#: name -> (required parameters, optional parameters)
EFFECTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {m.NAME: (m.REQUIRED, m.OPTIONAL) for m in MODULES}

_BY_NAME = {m.NAME: m for m in MODULES}


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
        check_type(name, k, v)
    if "axis" in flat and flat["axis"] not in ("x", "y", "both"):
        raise EffectError(f"effect '{name}': axis must be x, y or both (got {flat['axis']!r})")
    return {"name": name, **_BY_NAME[name].validate(flat, f"effect '{name}'")}


def apply_effects(effects: Iterable[Mapping], t: np.ndarray, base_dir: str | Path | None = None):
    """Translate effects into kernel-parameter overrides and external-force arrays.

    Parameters
    ----------
    effects : iterable of mappings
        Effect specifications (see module table).
    t : array
        Sample times (s) at which the external force is evaluated (held over each sample).
    base_dir : path, optional
        Folder relative to which an effect's file is found.

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
        _BY_NAME[e["name"]].apply(e, ov, f_x, f_y, t, base_dir)
    return ov, f_x, f_y
