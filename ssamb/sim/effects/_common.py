"""What the AMB's effect modules share: the error type, parameter checks, the axes of a sensor
effect, the sensor-path ratio an effect's evidence reads, and the merge of per-axis estimates."""
from __future__ import annotations

import math
import numbers

import numpy as np

from ...errors import InputError

__all__ = ["EffectError", "check_type", "axes_of", "ratio_path", "merge_axes", "SENSOR_AXES"]

#: the axes a sensor effect can act on
SENSOR_AXES = ("x", "y")


class EffectError(InputError):
    """An effect specification is invalid; the message names the effect and the parameter."""


def check_type(name: str, key: str, value) -> None:
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


def axes_of(axis: str) -> tuple[str, ...]:
    """``both`` -> ``("x", "y")``; one axis -> itself."""
    return ("x", "y") if axis == "both" else (axis,)


def ratio_path(ft, axis: str, st) -> dict | None:
    """The ratio that isolates the sensor of an axis.

    y: the self-sensing estimate over the evaluation sensor (plant changes cancel), unless that
    path is much less precise than the estimate over the coil current (an excitation that moves
    the rotor little, like current pulses, leaves both position sensors near their noise).
    """
    if axis == "y":
        a, b = ft.ratios.get("y_sensor"), ft.ratios.get("y")
        if a is None or b is None:
            return a or b
        precise = a["se_tau_s"] <= st.ratio_path_se_factor * b["se_tau_s"]
        return a if (a["n_lines"] >= st.ratio_path_min_lines and precise) else b
    return ft.ratios.get("x")


def merge_axes(name: str, key: str, axes: tuple, vals: np.ndarray, ses: np.ndarray, offset: float = 0.0) -> list[dict]:
    """One entry per axis, or one ``axis: both`` entry when the axes agree."""
    if len(axes) == 2:
        d = abs(vals[0] - vals[1])
        s = math.hypot(ses[0], ses[1])
        # the same within 3 standard errors, or within 2 % (standard errors of a long record
        # can be far below any practical difference)
        if d <= 3 * s or d <= 0.02 * max(abs(vals[0]), abs(vals[1]), 1e-12):
            w = 1 / np.maximum(ses, 1e-300) ** 2
            m = float(np.sum(w * vals) / np.sum(w))
            se = float(1 / math.sqrt(np.sum(w)))
            return [{"name": name, "params": {"axis": "both", key: m + offset},
                     "uncertainty": {key: se}, "per_axis": {a: {key: float(v + offset), "se": float(e)}
                                                          for a, v, e in zip(axes, vals, ses)}}]
    return [{"name": name, "params": {"axis": a, key: float(v + offset)}, "uncertainty": {key: float(e)}}
            for a, v, e in zip(axes, vals, ses)]


def sensor_keep(axes: tuple, se: np.ndarray, significant: np.ndarray) -> list:
    """The axes a sensor effect's report keeps: the significant ones; else those the data determine
    (a standard error of 1e4 marks a direction the data left to its prior); else all."""
    return ([i for i in range(len(axes)) if significant[i]]
            or [i for i in range(len(axes)) if np.isfinite(se[i]) and se[i] < 1e3] or list(range(len(axes))))


def sensor_restart(theta: np.ndarray, hints: dict, axes: tuple, key: str, combine) -> np.ndarray | None:
    """A sensor effect's parameters moved by what its residual still shows (``hints[key + axis]``,
    :func:`ratio_path`'s estimate on each axis where the evidence is significant): ``combine(fitted,
    shown)`` per such axis; None when no axis shows any."""
    shown = [a for a in (hints.get("axes") or ()) if (key + a) in hints and a in axes]
    if not shown:
        return None
    out = np.array(theta, float)
    for a in shown:
        i = axes.index(a)
        out[i] = combine(out[i], float(hints[key + a]))
    return out
