r"""Identification data: the fit metric, provenance hash, checks and input excitation."""
from __future__ import annotations

import hashlib
import json
import math
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np

from ..channels import ONE, structure, subsystem_data
from ..io import DataError

FS_HZ_DEFAULT = 83300.0


def nrmse_fit(y, yhat):
    r"""Normalised-root-mean-square fit in percent, per output channel (MATLAB ``compare``).

    .. math:: \mathrm{fit}_j = 100\left(1 - \frac{\|y_{:,j} - \hat y_{:,j}\|_2}
              {\|y_{:,j} - \bar y_j\|_2}\right)

    Parameters
    ----------
    y, yhat : array_like, shape (n_samples,) or (n_samples, n_channels)
        Measured and model outputs.

    Returns
    -------
    float or ndarray of shape (n_channels,)
        100 for a perfect model, 0 for the constant mean, negative when worse than the mean.
        Channels are never pooled. A constant channel gives ``nan`` (the fit is undefined),
        a non-finite prediction gives ``-inf``.
    """
    y = np.asarray(y, dtype=float)
    yhat = np.asarray(yhat, dtype=float)
    if y.shape != yhat.shape:
        raise ValueError(f"nrmse_fit: y has shape {y.shape}, yhat has shape {yhat.shape}")
    scalar = y.ndim == 1
    y2 = y.reshape(len(y), -1)
    yh2 = yhat.reshape(len(yhat), -1)
    num = np.linalg.norm(y2 - yh2, axis=0)
    den = np.linalg.norm(y2 - y2.mean(axis=0), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = 100.0 * (1.0 - num / den)
    fit = np.where(den > 0, fit, np.nan)
    fit = np.where(np.isfinite(yh2).all(axis=0) | (den == 0), fit, -np.inf)
    return float(fit[0]) if scalar else fit


def data_hash(u, y, fs_hz: float, input_names: Sequence[str], output_names: Sequence[str]) -> str:
    """SHA-256 of the identification data (values, names and rate): the model's provenance."""
    h = hashlib.sha256()
    h.update(json.dumps([float(fs_hz), list(input_names), list(output_names)]).encode())
    for a in (u, y):
        a = np.ascontiguousarray(a, dtype=np.float64)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _as_2d(a, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataError(f"{what} must be 1-D or 2-D (n_samples, n_channels), got shape {a.shape}")
    return a


def _names(names, n: int, prefix: str, what: str) -> tuple[str, ...]:
    if names is None:
        return tuple(f"{prefix}{i}" for i in range(n))
    names = tuple(str(s) for s in ([names] if isinstance(names, str) else names))
    if len(names) != n:
        raise DataError(f"{what}: {len(names)} name(s) {names} for {n} channel(s)")
    if len(set(names)) != n:
        raise DataError(f"{what}: duplicate channel names {names}")
    if ONE in names:
        raise DataError(f"{what}: the name '{ONE}' is reserved for the operating-point input")
    return names


def min_samples(n_inputs: int, n_outputs: int, ss_f: int, ss_p: int) -> int:
    r"""Shortest record for the horizons: the block-Hankel data matrix
    (:math:`(m+l)(f+p)` rows) must have at least twice as many columns
    (:math:`N - f - p + 1`) as rows."""
    rows = (n_inputs + n_outputs) * (ss_f + ss_p)
    return 2 * rows + ss_f + ss_p - 1


def check_io_data(u, y, input_names=None, output_names=None, ss_f: int = 30, ss_p: int = 30,
                  order: int | None = None):
    """Validate identification data; return ``(u, y, input_names, output_names)`` as 2-D arrays.

    Raises
    ------
    DataError
        Mismatched lengths, non-finite values (the channel and first sample are named), a
        constant input channel (no excitation, named), a record too short for the horizons,
        an order not below the future horizon.
    """
    u = _as_2d(u, "u")
    y = _as_2d(y, "y")
    input_names = _names(input_names, u.shape[1], "u", "input_names")
    output_names = _names(output_names, y.shape[1], "y", "output_names")
    if u.shape[0] != y.shape[0]:
        raise DataError(f"u has {u.shape[0]} samples but y has {y.shape[0]}: lengths must match")
    for arr, names in ((u, input_names), (y, output_names)):
        bad = ~np.isfinite(arr)
        if bad.any():
            j = int(np.argmax(bad.any(axis=0)))
            raise DataError(
                f"channel '{names[j]}' has {int(bad[:, j].sum())} non-finite value(s) (NaN/inf), "
                f"first at sample {int(np.argmax(bad[:, j]))}"
            )
    for j, name in enumerate(input_names):
        col = u[:, j]
        spread = np.ptp(col)
        if spread <= 1e-12 * max(1.0, float(np.max(np.abs(col)))):
            raise DataError(
                f"input channel '{name}' is constant ({col[0]:g}): no excitation, the model cannot "
                f"be identified from it (remove it or excite it)"
            )
    if ss_f < 1 or ss_p < 1:
        raise DataError(f"horizons must be positive (ss_f={ss_f}, ss_p={ss_p})")
    if order is not None:
        if order < 1:
            raise DataError(f"order must be >= 1 (got {order})")
        if order >= ss_f:
            raise DataError(f"order {order} must be smaller than the future horizon ss_f={ss_f}")
        if order > y.shape[1] * ss_f:
            raise DataError(f"order {order} exceeds n_outputs*ss_f = {y.shape[1] * ss_f}")
    need = min_samples(u.shape[1], y.shape[1], ss_f, ss_p)
    if u.shape[0] < need:
        raise DataError(
            f"data too short: {u.shape[0]} samples, the horizons ss_f={ss_f}, ss_p={ss_p} with "
            f"{u.shape[1]} input(s) and {y.shape[1]} output(s) need at least {need}"
        )
    return u, y, input_names, output_names


class IOData(NamedTuple):
    """Input/output data of one subsystem: ``u`` (N, m), ``y`` (N, l) and the channel names."""

    u: np.ndarray
    y: np.ndarray
    input_names: tuple
    output_names: tuple


def subsystem_io(arrays: Mapping[str, Any], subsystem: str, variant: str | None = None) -> IOData:
    """Extract the identification data of one subsystem from a simulator/measured data dict.

    Parameters
    ----------
    arrays : mapping
        Columns of the measured-data format (``t``, ``x_meas``, ``y_meas``, ``y_ss``,
        ``i_ypos`` ... ``u_x``, ``u_y`` and, optionally, ``inj_x``, ``inj_y``; a missing
        injection means none).
    subsystem : {'plant', 'amplifier', 'selfsensing'}
    variant : str, optional
        The structure (:data:`ssamb.channels.VARIANTS`; default ours): e.g. ``'full'`` for the
        paper's 4-input amplifier, ``'current'`` for its ``i_ypos -> y_ss`` self-sensing.

    Returns
    -------
    IOData
        ``(u, y, input_names, output_names)``; a 4-tuple.

    Raises
    ------
    DataError
        A column the structure needs is missing (named), or columns differ in length.
    """
    st = structure(subsystem, variant)
    need = {c if not c.endswith("_cmd") else "u_" + c[2] for c in st.inputs + st.outputs}
    missing = sorted(c for c in need if c not in arrays)
    if missing:
        raise DataError(f"{subsystem}: missing column(s) {', '.join(missing)}")
    lens = {len(np.asarray(arrays[c]).ravel()) for c in need}
    if len(lens) != 1:
        raise DataError(f"{subsystem}: columns have different lengths {sorted(lens)}")
    u, y = subsystem_data(arrays, st)
    return IOData(u, y, st.inputs, st.outputs)


def input_excitation(u, input_names=None, hankel_rows: int | None = None) -> dict:
    r"""How well the input directions are excited.

    The inputs are centred and scaled to unit standard deviation (as SIPPY does) and the
    singular values :math:`\sigma_i` of the :math:`N \times m` matrix are returned, relative to
    the largest, with the right singular vectors (the directions). A ratio near zero means a
    direction (e.g. the common mode of two coil currents) the data cannot identify.

    With ``hankel_rows = f`` the relative singular values of the block-Hankel matrix of the
    scaled inputs (:math:`f m` rows: the input part of SIPPY's data matrix) are returned too:
    persistency of excitation of order f. Small values there mean that some input channels are
    (dynamically) predictable from the others -- at 83.3 kHz the smooth position signals alone
    make a few of them small, and in closed loop the positions are causal functions of the
    commands, which makes the split between command and position paths of the amplifier
    unidentifiable without an independent excitation of the rotor.

    Returns
    -------
    dict
        ``relative_singular_values`` (m,), ``directions`` (m, m) rows = directions in the scaled
        inputs, ``std`` (m,), ``condition_number``; with ``hankel_rows``:
        ``hankel_relative_singular_values`` (f m,) and ``hankel_min_relative_sv``.
    """
    u = _as_2d(u, "u")
    std = u.std(axis=0)
    std = np.where(std > 0, std, 1.0)
    z = (u - u.mean(axis=0)) / std
    _, s, vt = np.linalg.svd(z / math.sqrt(len(z)), full_matrices=False)
    rel = s / s[0] if s[0] > 0 else s
    out = {
        "input_names": list(input_names) if input_names is not None else None,
        "relative_singular_values": rel,
        "directions": vt,
        "std": std,
        "condition_number": float(s[0] / s[-1]) if s[-1] > 0 else math.inf,
    }
    if hankel_rows is not None:
        f = int(hankel_rows)
        if not 1 <= f < len(z):
            raise ValueError(f"hankel_rows must be in [1, {len(z) - 1}] (got {hankel_rows})")
        H = np.lib.stride_tricks.sliding_window_view(z, (f, z.shape[1]))[:, 0].reshape(len(z) - f + 1, -1)
        ev = np.linalg.eigvalsh(H.T @ H / len(H))[::-1]  # Gram matrix: sigma^2 of the Hankel matrix
        hs = np.sqrt(np.clip(ev, 0.0, None))
        hs = hs / hs[0] if hs[0] > 0 else hs
        out["hankel_relative_singular_values"] = hs
        out["hankel_min_relative_sv"] = float(hs[-1])
    return out

