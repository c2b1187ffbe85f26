r"""Measured data for the close-the-loop analysis: channels, excitation, and the split.

A :class:`Record` holds the logged channels (double precision), the excitation inputs that
drive the replay (``r_x``, ``r_y`` from the file; ``inj_x``, ``inj_y`` from the file or,
if absent, regenerated from ``meta``) and what ``meta`` says about the excitation.

The split (:class:`Split`) discards a start-up interval, then cuts the rest into a fitting
part and a held-out part. When the excitation is periodic (a multisine whose
``samples_per_period`` is in ``meta`` and whose samples repeat), the cut points fall on whole
periods, so that both parts are leakage-free for the DFT at the excited lines.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ..io import DataError

__all__ = ["CHANNELS", "POSITION_CHANNELS", "CURRENT_CHANNELS", "VIEWS", "Record", "Split",
           "record_from_arrays", "make_split", "views", "unit_of", "pwm_lines"]

#: logged channels compared with the model
CHANNELS = ("x_meas", "y_meas", "y_ss", "i_ypos", "i_yneg", "i_xpos", "i_xneg", "u_x", "u_y")
POSITION_CHANNELS = ("x_meas", "y_meas", "y_ss")
CURRENT_CHANNELS = ("i_ypos", "i_yneg", "i_xpos", "i_xneg")
#: derived views: positions, differential (d) and common-mode (c) coil currents, controller outputs
VIEWS = ("x_meas", "y_ss", "y_meas", "d_x", "d_y", "c_x", "c_y", "u_x", "u_y")
#: the view that carries each axis' position as the controller sees it, and its actuator view
SENSOR_VIEW = {"x": "x_meas", "y": "y_ss"}
ACTUATOR_VIEW = {"x": "d_x", "y": "d_y"}


def pwm_lines(f_pwm_hz: float, fs_hz: float, harmonics: int) -> tuple:
    r"""The PWM carrier's first ``harmonics`` harmonics as the sampling sees them (aliased into
    :math:`[0, f_s/2]`: :math:`|k f_{pwm} - f_s\,\mathrm{round}(k f_{pwm}/f_s)|`), distinct, sorted.

    A two-state amplifier's ripple is a periodic waveform at the carrier; its harmonics alias to
    fixed frequencies (30 kHz at 83.3 kHz: 30, 23.3, 6.7, 36.7, 16.6, 13.4, 39.9, 10.1 kHz). Their
    amplitude and phase carry the ripple's shape: the dead time, the supply voltage and the
    coils' inductance, which the low-frequency response barely shows.
    """
    out = set()
    for k in range(1, harmonics + 1):
        f = k * f_pwm_hz
        a = abs(f - fs_hz * round(f / fs_hz))
        if 0 < a < fs_hz / 2:
            out.add(round(a, 6))
    return tuple(sorted(out))


def unit_of(name: str) -> str:
    """SI unit of a channel or view."""
    return "m" if name in POSITION_CHANNELS else "A"


def views(ch: Mapping[str, np.ndarray]) -> dict:
    r"""Derived views of channel arrays (measured, model or residual alike).

    .. math:: d_x = (i_{xpos} - i_{xneg})/2, \quad c_x = (i_{xpos} + i_{xneg})/2

    and the same for y; positions and controller outputs are passed through.
    """
    out = {k: ch[k] for k in ("x_meas", "y_ss", "y_meas", "u_x", "u_y")}
    out["d_x"] = 0.5 * (ch["i_xpos"] - ch["i_xneg"])
    out["d_y"] = 0.5 * (ch["i_ypos"] - ch["i_yneg"])
    out["c_x"] = 0.5 * (ch["i_xpos"] + ch["i_xneg"])
    out["c_y"] = 0.5 * (ch["i_ypos"] + ch["i_yneg"])
    return out


@dataclass(frozen=True)
class Record:
    """Measured data ready for the analysis.

    Attributes
    ----------
    fs_hz : float
    channels : dict
        :data:`CHANNELS` as float64 arrays.
    inputs : dict
        ``r_x``, ``r_y``, ``inj_x``, ``inj_y`` (float64) that drive the replay.
    excitation : dict
        The excitation described by ``meta`` (``kind``, ``point``, ``axis``, ...), normalised.
    excited_axes : tuple
        Axes whose reference or injection varies.
    signal : dict
        Per excited axis, the excitation signal used as the instrument of the frequency
        analysis (the reference if it varies, otherwise the injection).
    n_period : int or None
        Samples per period when the excitation is periodic (verified on the samples).
    lines_hz : numpy.ndarray or None
        Excited lines of a multisine.
    start : str
        ``levitated`` or ``rest``.
    settle_s : float or None
        Pre-roll of the data's simulation, if ``meta`` records it.
    acquisition : dict
        The logging chain (``meta.acquisition``: the logger's anti-alias filter, validated;
        empty when none), which the replay applies to the model's channels too.
    device_lines_hz : tuple
        Lines the device itself makes whatever the excitation: the PWM carrier's harmonics,
        aliased by the sampling (:func:`pwm_lines`; set by the comparison, which knows the
        model's carrier). They are features, and never candidates for a line the model lacks.
    meta : dict
    """

    fs_hz: float
    channels: dict
    inputs: dict
    excitation: dict
    excited_axes: tuple
    signal: dict
    n_period: int | None
    lines_hz: np.ndarray | None
    start: str
    settle_s: float | None
    acquisition: dict = field(default_factory=dict)
    device_lines_hz: tuple = ()
    meta: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.channels["x_meas"])

    @property
    def duration_s(self) -> float:
        return self.n / self.fs_hz


def _excitation_of(meta: Mapping) -> dict:
    exc = meta.get("excitation")
    if exc is None and "kind" in meta and meta.get("kind") not in ("rig", "simulation"):
        exc = meta   # a flat meta: {kind: multisine, ...}
    return dict(exc or {"kind": "unknown"})


def _regenerate_injection(exc: Mapping, fs_hz: float, n: int, source: str) -> dict:
    """Injection arrays of a ``point: current`` excitation, rebuilt from ``meta``."""
    from ..sim.api import excitation_arrays

    spec = {k: v for k, v in exc.items()
            if k not in ("axis_seeds", "lines_hz", "samples_per_period", "seed", "duration_s",
                         "fs_hz", "amplitude", "unit")}
    seed = exc.get("seed")
    if seed is None:
        raise DataError(f"{source}: columns 'inj_x'/'inj_y' are missing and meta.excitation has no "
                        "'seed' to regenerate the current injection")
    try:
        _, arrs, _ = excitation_arrays(spec, fs_hz, n / fs_hz, int(seed))
    except ValueError as exc_err:
        raise DataError(f"{source}: columns 'inj_x'/'inj_y' are missing and the injection cannot be "
                        f"regenerated from meta.excitation ({exc_err})") from None
    out = {}
    for k in ("inj_x", "inj_y"):
        a = np.asarray(arrs[k], float)
        if len(a) < n:
            a = np.concatenate([a, np.zeros(n - len(a))])
        out[k] = a[:n]
    return out


def record_from_arrays(arrays: Mapping, meta: Mapping, fs_model_hz: float, source: str = "data") -> Record:
    """Build a :class:`Record` from validated measured-data arrays and ``meta``.

    Raises
    ------
    DataError
        ``fs_hz`` differs from the model's controller rate, or a current injection described in
        ``meta`` cannot be recovered.
    """
    fs = float(np.asarray(arrays["fs_hz"]))
    if abs(fs - fs_model_hz) > 1e-6 * fs_model_hz:
        raise DataError(f"{source}: 'fs_hz' = {fs:g} Hz differs from the model's controller rate "
                        f"controller.fs_hz = {fs_model_hz:g} Hz; the replay runs at the controller rate "
                        "(resample the data or use the matching config)")
    ch = {c: np.asarray(arrays[c], dtype=np.float64) for c in CHANNELS}
    n = len(ch["x_meas"])
    exc = _excitation_of(meta)
    inputs = {k: np.asarray(arrays[k], dtype=np.float64) for k in ("r_x", "r_y")}
    if "inj_x" in arrays and "inj_y" in arrays:
        for k in ("inj_x", "inj_y"):
            a = np.asarray(arrays[k], dtype=np.float64)
            if a.shape != (n,) or not np.all(np.isfinite(a)):
                raise DataError(f"{source}: optional column '{k}' must have {n} finite samples")
            inputs[k] = a
    elif exc.get("point") == "current" and exc.get("kind") not in (None, "none", "unknown"):
        inputs.update(_regenerate_injection(exc, fs, n, source))
    else:
        inputs["inj_x"] = np.zeros(n)
        inputs["inj_y"] = np.zeros(n)
    excited, signal = [], {}
    for ax in ("x", "y"):
        r, inj = inputs["r_" + ax], inputs["inj_" + ax]
        if np.ptp(r) > 0:
            excited.append(ax)
            signal[ax] = r
        elif np.ptp(inj) > 0:
            excited.append(ax)
            signal[ax] = inj
    n_period = None
    lines = None
    spp = exc.get("samples_per_period")
    if exc.get("kind") == "multisine" and spp:
        spp = int(spp)
        ok = spp >= 16 and n >= 2 * spp and all(
            np.allclose(s[spp:], s[:-spp], rtol=0, atol=1e-6 * max(np.max(np.abs(s)), 1e-30))
            for s in signal.values())
        if ok:
            n_period = spp
            if exc.get("lines_hz"):
                lines = np.asarray(exc["lines_hz"], float)
    settle = meta.get("settle_s")
    from ..acquisition import validate_acquisition

    acq = validate_acquisition(meta.get("acquisition"), source, fs, key="meta.acquisition", error=DataError)
    return Record(fs_hz=fs, channels=ch, inputs=inputs, excitation=exc, excited_axes=tuple(excited),
                  signal=signal, n_period=n_period, lines_hz=lines,
                  start=str(meta.get("start", "levitated")),
                  settle_s=None if settle is None else float(settle), acquisition=acq, meta=dict(meta))


@dataclass(frozen=True)
class Split:
    """Sample ranges of the analysis.

    ``[i0, i_fit)`` is the fitting part and ``[i_fit, i_end)`` the held-out part (``i0`` after
    the discarded start-up). With a periodic excitation all boundaries are whole periods
    (``n_period``) counted from the start of the record.
    """

    i0: int
    i_fit: int
    i_end: int
    n_period: int | None

    @property
    def fit(self) -> slice:
        return slice(self.i0, self.i_fit)

    @property
    def hold(self) -> slice:
        return slice(self.i_fit, self.i_end)

    @property
    def fit_fraction(self) -> float:
        return (self.i_fit - self.i0) / (self.i_end - self.i0)


def make_split(rec: Record, fit_fraction: float, discard_s: float, min_fit_s: float,
               min_holdout_s: float, source: str = "data") -> Split:
    """Split a record; periodic excitations are cut on whole periods (at least 2 fit, 1 held out).

    Raises
    ------
    DataError
        The record is too short to give a fitting part of ``min_fit_s`` and a held-out part of
        ``min_holdout_s`` after discarding ``discard_s`` of start-up.
    """
    fs, n = rec.fs_hz, rec.n
    need = discard_s + min_fit_s + min_holdout_s
    too_short = DataError(
        f"{source}: too short to split: {n / fs:.4g} s of data; the analysis discards {discard_s:g} s of "
        f"start-up and needs at least {min_fit_s:g} s to fit and {min_holdout_s:g} s held out "
        f"({need:g} s in all)")
    p = rec.n_period
    if p is not None:
        k0 = math.ceil(discard_s * fs / p - 1e-9)
        n_per = n // p - k0
        k_fit = int(round(fit_fraction * n_per))
        # at least 2 periods on each side when possible (off-grid noise bins need 2 periods)
        k_fit = min(max(k_fit, 2), n_per - (2 if n_per >= 4 else 1))
        if n_per >= 3 and k_fit * p >= min_fit_s * fs and (n_per - k_fit) * p >= min_holdout_s * fs:
            return Split(i0=k0 * p, i_fit=(k0 + k_fit) * p, i_end=(k0 + n_per) * p, n_period=p)
    i0 = int(math.ceil(discard_s * fs))
    rest = n - i0
    i_fit = i0 + int(round(fit_fraction * rest))
    if rest <= 0 or (i_fit - i0) < min_fit_s * fs or (n - i_fit) < min_holdout_s * fs:
        raise too_short
    return Split(i0=i0, i_fit=i_fit, i_end=n, n_period=None)
