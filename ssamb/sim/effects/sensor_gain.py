r"""``sensor_gain``: a scale error of the position measurement.

Physics: the position the controller receives is :math:`g\,x` (kernel parameters ``GAIN_X``,
``GAIN_Y``; gains of several effects multiply).

Signature: the sensor path's measured/model ratio has a flat gain :math:`\ne 1` and no phase
(the loop's integral action hides a gain error from the position offset; it shows in the
excited response). Evidence: :math:`(\hat\alpha/\sigma_\alpha)^2` per axis, two-sided.

Fit: :math:`(g_x - 1, g_y - 1)`. A y sensor gain scales the calibrated DCM estimate,
:math:`y_{ss} = G(g\,y_{raw} + o)`: it is the DCM calibration's own error (gain :math:`Gg`,
offset :math:`Go`), so when the calibration gain is calibrated the effect acts on x only.
"""
from __future__ import annotations

import functools

import numpy as np

from ...device import EffectModel
from ._common import EffectError, axes_of, merge_axes, sensor_keep, sensor_restart
from .sensor_delay import fit_axes, sensor_claim, sensor_evidence

NAME = "sensor_gain"
REQUIRED = ("axis", "gain")
OPTIONAL = ()
SIGNATURE = "flat gain ratio of the sensor path (measured/model) different from 1, no phase"
SEARCHABLE = True
NEEDS_HINT = False
ORDER = 4

#: the calibration parameter a y sensor gain is indistinguishable from
DCM_GAIN_KEY = "selfsensing.calibration_gain_error"


def validate(p: dict, where: str) -> dict:
    if not float(p["gain"]) > 0:
        raise EffectError(f"{where}: gain must be > 0 (got {p['gain']})")
    return p


def apply(e: dict, ov: dict, f_x, f_y, t, base_dir) -> None:
    for ax in axes_of(e["axis"]):
        key = "GAIN_" + ax.upper()
        ov[key] = ov.get(key, 1.0) * float(e["gain"])


def evidence(ft, alpha: float, st) -> dict:
    return sensor_evidence(NAME, ft, alpha, "alpha", st)


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return sensor_claim(ft, st, "chi2_alpha")


def model(hints: dict, record, st) -> EffectModel | str:
    # every sensor axis, excited or not (sensor_delay.fit_axes); a y gain is the DCM calibration's
    # own error when that is calibrated
    axes = tuple(a for a in fit_axes(hints, tuple(record.excited_axes))
                 if not (a == "y" and DCM_GAIN_KEY in (st.calibration or {})))
    th = np.array([float(hints.get("gain_" + a, 1.0)) - 1.0 for a in axes])
    return EffectModel(NAME, tuple(f"gain_{a}_minus_1" for a in axes), th, np.maximum(0.2 * np.abs(th), 1e-2),
                       np.full(len(axes), -0.9), np.full(len(axes), 9.0),
                       lambda t: [{"name": NAME, "axis": a, "gain": float(1.0 + v)} for a, v in zip(axes, t)],
                       {"axes": axes}, restart=functools.partial(_restart, axes=axes))


def _restart(theta: np.ndarray, hints: dict, axes: tuple) -> np.ndarray | None:
    r"""The fitted gains times the gains their residual still shows on the axes where its
    evidence is significant (``hints``: :func:`evidence` of the residual),
    :math:`(1 + \theta) g_r - 1`; None when no axis shows one."""
    return sensor_restart(theta, hints, axes, "gain_", lambda g, r: (1.0 + g) * r - 1.0)


def report(m: EffectModel, theta, se, significant) -> list[dict]:
    axes = m.fixed["axes"]
    keep = sensor_keep(axes, se, significant)
    return merge_axes(NAME, "gain", tuple(axes[i] for i in keep), theta[keep], se[keep], 1.0)
