"""Excitation signals: rectangular pulses, random-phase multisine, sine sweep, step.

Every generator is a pure function of its arguments (explicit integer seeds, no global random
state) and returns float64 samples at ``fs_hz`` (the controller rate, 83 300 Hz, unless the caller
says otherwise), in SI units: metres for position references, amperes for current injections.
Sample ``n`` is at ``t[n] = n / fs_hz``; a record of ``duration_s`` has
``round(duration_s * fs_hz)`` samples.

Where each signal is used in the paper:

* :func:`pulses` -- "rectangular pulses injected prior to the power amplifiers" for the
  closed-loop identification of the nominal subsystem models (section 3);
* :func:`multisine` -- the "random-phase multi-sine signal (with an amplitude of 100 um and
  frequency content stretching from 5 Hz to 26 Hz)" applied at the system input to measure the
  additive uncertainty of eq. (6) (section 5, Fig. 7);
* :func:`sweep` -- the "99 um amplitude frequency sweep signal stretching from 11 Hz to 50 Hz"
  used to provoke delevitation (section 6.2, Fig. 9); :func:`sweep_frequency_at` converts the
  delevitation time into a sweep frequency;
* :func:`step` -- a plain reference step (commissioning, tests);
* :func:`make_excitation` -- builds any of them from the ``excitation`` dictionary of a
  ``config.yaml`` experiment or of a rig scenario file.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

__all__ = [
    "Multisine",
    "Excitation",
    "time_vector",
    "n_samples",
    "pulses",
    "pulses_psd",
    "multisine",
    "sweep",
    "sweep_frequency_at",
    "sweep_phase_rad",
    "step",
    "make_excitation",
]

_SWEEP_LAWS = ("linear", "log")


# ---------------------------------------------------------------------------------------------
# argument checks
# ---------------------------------------------------------------------------------------------
def _real(name: str, value: Any, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if positive and v <= 0.0:
        raise ValueError(f"{name} must be > 0, got {value!r}")
    if nonneg and v < 0.0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")
    return v


def _int(name: str, value: Any, *, minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        # accept floats that are exact integers (YAML often gives 4.0)
        if isinstance(value, numbers.Real) and not isinstance(value, bool) and float(value).is_integer():
            value = int(value)
        else:
            raise ValueError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if minimum is not None and v < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")
    return v


def _seed(value: Any) -> int:
    if value is None:
        raise ValueError("seed is required (an integer >= 0) for a random excitation; got None")
    return _int("seed", value, minimum=0)


def n_samples(fs_hz: float, duration_s: float) -> int:
    """Number of samples of a record: ``round(duration_s * fs_hz)`` (at least 1)."""
    fs_hz = _real("fs_hz", fs_hz, positive=True)
    duration_s = _real("duration_s", duration_s, positive=True)
    return max(1, int(round(duration_s * fs_hz)))


def time_vector(fs_hz: float, duration_s: float) -> np.ndarray:
    """Sample instants ``t[n] = n / fs_hz`` for ``n = 0 .. n_samples(fs_hz, duration_s) - 1``."""
    return np.arange(n_samples(fs_hz, duration_s), dtype=np.float64) / float(fs_hz)


# ---------------------------------------------------------------------------------------------
# rectangular pulses
# ---------------------------------------------------------------------------------------------
def _width_bounds_samples(fs_hz: float, min_width_s: float, max_width_s: float) -> tuple[int, int]:
    lo = math.ceil(min_width_s * fs_hz - 1e-9)
    hi = math.floor(max_width_s * fs_hz + 1e-9)
    lo = max(lo, 1)
    if hi < lo:
        raise ValueError(
            f"min_width_s={min_width_s!r} and max_width_s={max_width_s!r}: no whole number of "
            f"samples at fs_hz={fs_hz!r} lies in [min_width_s, max_width_s]"
        )
    return lo, hi


def pulses(
    fs_hz: float,
    duration_s: float,
    amplitude: float,
    min_width_s: float,
    max_width_s: float,
    seed: int,
) -> np.ndarray:
    r"""Train of rectangular pulses of alternating sign (a random binary signal).

    The signal switches between :math:`+a` and :math:`-a` (``a = amplitude``); the sign
    alternates at every switching instant and each hold time is drawn independently and
    uniformly from the whole numbers of samples in ``[min_width_s, max_width_s]``
    (``ceil(min_width_s fs)`` to ``floor(max_width_s fs)`` samples). The first level (+a or
    -a) is random. Only the last pulse may be shorter than ``min_width_s``: the record ends
    inside it.

    Why binary and alternating (paper section 3, "rectangular pulses" injected before the power
    amplifiers):

    * a two-level signal has crest factor 1, so it puts the most power into the loop for a
      given peak current (the amplifiers and the airgap bound the peak, not the power);
      a three-level 0/+a/-a signal spends time at 0 and excites less for the same peak;
    * alternating signs make every pulse exactly one hold time long (independent random signs
      would merge equal neighbours into pulses longer than ``max_width_s``) and keep the
      running integral a zero-mean random walk of the width differences (no drift of the
      operating point);
    * with ``min_width_s < max_width_s`` the spectrum below is continuous and strictly positive
      on (0, fs/2], so the signal is persistently exciting of any order. With equal widths it
      degenerates to a square wave (lines only).

    Spectrum (alternating renewal process, hold times :math:`T` in samples with characteristic
    function :math:`\phi(\theta) = E[e^{-j\theta T}]`, mean :math:`\mu`): the two-sided PSD per
    sample is

    .. math:: S(\theta) = \frac{a^2}{\mu \sin^2(\theta/2)}
              \,\mathrm{Re}\,\frac{1 - \phi(\theta)}{1 + \phi(\theta)},

    flat below about :math:`f_s / (\pi \mu)` and falling at 20 dB/decade above it, with ripples
    at multiples of ``1/min_width_s``; :func:`pulses_psd` evaluates it (one-sided, A^2/Hz).
    For the identification experiment (0.2-4 ms at 83.3 kHz) the knee is near 150 Hz.

    Parameters
    ----------
    fs_hz : float
        Sampling rate (Hz).
    duration_s : float
        Record length (s).
    amplitude : float
        Pulse height ``a`` (SI unit of the injected quantity, e.g. A); must be >= 0.
    min_width_s, max_width_s : float
        Bounds of the hold time (s), ``0 < min_width_s <= max_width_s``.
    seed : int
        Seed of :func:`numpy.random.default_rng`; the same seed gives the same signal.

    Returns
    -------
    numpy.ndarray
        float64 samples, each exactly ``+amplitude`` or ``-amplitude``.
    """
    fs_hz = _real("fs_hz", fs_hz, positive=True)
    n = n_samples(fs_hz, duration_s)
    amplitude = _real("amplitude", amplitude, nonneg=True)
    min_width_s = _real("min_width_s", min_width_s, positive=True)
    max_width_s = _real("max_width_s", max_width_s, positive=True)
    if min_width_s > max_width_s:
        raise ValueError(f"min_width_s={min_width_s!r} must be <= max_width_s={max_width_s!r}")
    lo, hi = _width_bounds_samples(fs_hz, min_width_s, max_width_s)
    rng = np.random.default_rng(_seed(seed))
    first = 1.0 if rng.integers(0, 2) == 1 else -1.0
    n_pulses = n // lo + 2  # enough pulses to cover the record in the worst case
    widths = rng.integers(lo, hi + 1, size=n_pulses)
    signs = first * np.where(np.arange(n_pulses) % 2 == 0, 1.0, -1.0)
    x = np.repeat(signs, widths)[:n]
    return np.ascontiguousarray(amplitude * x, dtype=np.float64)


def pulses_psd(
    freqs_hz: np.ndarray,
    fs_hz: float,
    amplitude: float,
    min_width_s: float,
    max_width_s: float,
) -> np.ndarray:
    r"""One-sided power spectral density of :func:`pulses` (amplitude^2 / Hz).

    Evaluates :math:`G(f) = 2 S(2\pi f / f_s) / f_s` with :math:`S` the per-sample two-sided PSD
    given in :func:`pulses` (hold times uniform on the whole numbers of samples in
    ``[min_width_s, max_width_s]``). At :math:`f = 0` the limit
    :math:`S(0) = a^2\,\mathrm{var}(T)/\mu` is used. Valid for ``0 <= f <= fs/2``.
    """
    f = np.asarray(freqs_hz, dtype=np.float64)
    fs_hz = _real("fs_hz", fs_hz, positive=True)
    a = _real("amplitude", amplitude, nonneg=True)
    lo, hi = _width_bounds_samples(fs_hz, min_width_s, max_width_s)
    widths = np.arange(lo, hi + 1, dtype=np.float64)
    mu = widths.mean()
    var = widths.var()
    theta = 2.0 * np.pi * f / fs_hz
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.exp(-1j * np.multiply.outer(theta, widths)).mean(axis=-1)
        s = a**2 / (mu * np.sin(theta / 2.0) ** 2) * np.real((1.0 - phi) / (1.0 + phi))
    s = np.where(np.abs(theta) < 1e-12, a**2 * var / mu, s)
    return 2.0 * s / fs_hz


# ---------------------------------------------------------------------------------------------
# multisine
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Multisine:
    """A periodic multisine record (see :func:`multisine`).

    Attributes
    ----------
    t : numpy.ndarray
        Sample instants (s).
    x : numpy.ndarray
        Samples (unit of ``amplitude``).
    lines_hz : numpy.ndarray
        Excited frequencies (Hz), ``lines_bins * fs_hz / samples_per_period``.
    samples_per_period : int
        ``N = fs_hz / f_resolution_hz``.
    lines_bins : numpy.ndarray
        DFT bins (over one period of ``N`` samples) of the excited lines.
    phases_rad : numpy.ndarray
        Phase of each cosine component at ``t = 0`` (after the start shift).
    line_amplitude : float
        Amplitude of every cosine component (all equal).
    fs_hz : float
        Sampling rate (Hz).
    periods : float
        Number of periods in the record (an integer unless a ``duration_s`` cut the record).
    """

    t: np.ndarray
    x: np.ndarray
    lines_hz: np.ndarray
    samples_per_period: int
    lines_bins: np.ndarray
    phases_rad: np.ndarray
    line_amplitude: float
    fs_hz: float
    periods: float

    @property
    def period_s(self) -> float:
        """Length of one period (s)."""
        return self.samples_per_period / self.fs_hz


def _samples_per_period(fs_hz: float, f_resolution_hz: float) -> int:
    ratio = fs_hz / f_resolution_hz
    n = int(round(ratio))
    if n < 1 or abs(ratio - n) > 1e-9 * max(1.0, abs(ratio)):
        raise ValueError(
            f"fs_hz / f_resolution_hz = {fs_hz!r} / {f_resolution_hz!r} = {ratio!r} is not an "
            "integer (relative tolerance 1e-9): a multisine period must hold a whole number of "
            "samples; choose f_resolution_hz so that fs_hz / f_resolution_hz is an integer"
        )
    return n


def _multisine_bins(fs_hz: float, f_min_hz, f_max_hz, f_resolution_hz) -> tuple[int, np.ndarray]:
    """Samples per period and the DFT bins of the lines in ``[f_min_hz, f_max_hz]`` (DC and
    Nyquist excluded); the arguments are checked (the message names the argument)."""
    f_min_hz = _real("f_min_hz", f_min_hz, nonneg=True)
    f_max_hz = _real("f_max_hz", f_max_hz, positive=True)
    f_resolution_hz = _real("f_resolution_hz", f_resolution_hz, positive=True)
    if f_max_hz < f_min_hz:
        raise ValueError(f"f_max_hz={f_max_hz!r} must be >= f_min_hz={f_min_hz!r}")
    if f_max_hz >= fs_hz / 2.0:
        raise ValueError(f"f_max_hz={f_max_hz!r} must be below the Nyquist frequency fs_hz/2={fs_hz / 2!r}")
    n_per = _samples_per_period(fs_hz, f_resolution_hz)
    k_lo = max(1, math.ceil(f_min_hz / f_resolution_hz - 1e-9))
    k_hi = min(math.floor(f_max_hz / f_resolution_hz + 1e-9), (n_per - 1) // 2)  # strictly below Nyquist
    if k_hi < k_lo:
        raise ValueError(
            f"no multiple of f_resolution_hz={f_resolution_hz!r} lies in "
            f"[f_min_hz={f_min_hz!r}, f_max_hz={f_max_hz!r}] (DC excluded)"
        )
    return n_per, np.arange(k_lo, k_hi + 1, dtype=np.int64)


def multisine(
    fs_hz: float,
    amplitude: float,
    f_min_hz: float,
    f_max_hz: float,
    f_resolution_hz: float,
    periods: int,
    seed: int,
    *,
    phase: str = "random",
    start_near_zero: bool = True,
    amplitude_definition: str = "peak",
) -> Multisine:
    r"""Periodic multisine with equal-amplitude lines on every multiple of ``f_resolution_hz``.

    One period of :math:`N = f_s / f_0` samples (:math:`f_0` = ``f_resolution_hz``) is

    .. math:: x[n] = c \sum_{k \in K} \cos\!\left(\frac{2\pi k n}{N} + \varphi_k\right),
              \qquad K = \{k \ge 1 : f_{min} \le k f_0 \le f_{max},\ k < N/2\},

    with phases :math:`\varphi_k` independent and uniform on :math:`[0, 2\pi)` (``phase=
    "random"``, the paper's "random-phase multi-sine", section 5) or Schroeder's
    :math:`\varphi_k = -\pi i (i-1) / |K|` (``phase="schroeder"``, low crest factor), and
    :math:`c` chosen so that :math:`\max_n |x[n]|` over a period equals ``amplitude`` exactly
    (``amplitude_definition="peak"``: our reading of the paper's "amplitude of 100 um") or
    :math:`c` = ``amplitude`` (``"per_line"``: every line has that amplitude). The period is
    built with an inverse real FFT, so the DFT of any whole period is zero outside the excited
    bins (no leakage) and the record is exactly periodic: ``x[n + N] == x[n]``.

    With ``start_near_zero`` the period is rotated to start at its smallest sample (no jump of
    the reference at t = 0); the shift only adds a linear phase, included in ``phases_rad``.

    Parameters
    ----------
    fs_hz : float
        Sampling rate (Hz).
    amplitude : float
        Peak value over a period (e.g. ``amplitude_m = 1e-4``).
    f_min_hz, f_max_hz : float
        Band of the excited lines (Hz), inclusive (to 1e-9 of a line), below ``fs_hz / 2``.
    f_resolution_hz : float
        Line spacing and inverse period (Hz); ``fs_hz / f_resolution_hz`` must be an integer.
    periods : int
        Number of whole periods in the record (>= 1).
    seed : int
        Seed of :func:`numpy.random.default_rng` (used by ``phase="random"``).
    phase : {"random", "schroeder"}
        Phase law.
    start_near_zero : bool
        Rotate the period to start at its smallest-magnitude sample.
    amplitude_definition : {"peak", "per_line"}
        What ``amplitude`` is: the peak of the signal, or the amplitude of each line.

    Returns
    -------
    Multisine

    Raises
    ------
    ValueError
        If ``fs_hz / f_resolution_hz`` is not an integer, no line lies in the band, or an
        argument is out of range (the message names the argument).
    """
    fs_hz = _real("fs_hz", fs_hz, positive=True)
    amplitude = _real("amplitude", amplitude, nonneg=True)
    periods = _int("periods", periods, minimum=1)
    if phase not in ("random", "schroeder"):
        raise ValueError(f"phase must be 'random' or 'schroeder', got {phase!r}")
    if amplitude_definition not in ("peak", "per_line"):
        raise ValueError(f"amplitude_definition must be 'peak' or 'per_line', got {amplitude_definition!r}")
    n_per, bins = _multisine_bins(fs_hz, f_min_hz, f_max_hz, f_resolution_hz)
    n_lines = bins.size
    if phase == "random":
        phases = np.random.default_rng(_seed(seed)).uniform(0.0, 2.0 * np.pi, size=n_lines)
    else:
        i = np.arange(1, n_lines + 1, dtype=np.float64)
        phases = np.mod(-np.pi * i * (i - 1) / n_lines, 2.0 * np.pi)
    spec = np.zeros(n_per // 2 + 1, dtype=np.complex128)
    spec[bins] = np.exp(1j * phases) * (n_per / 2.0)
    one = np.fft.irfft(spec, n=n_per)  # = sum_k cos(2 pi k n / N + phi_k)
    if start_near_zero:
        n0 = int(np.argmin(np.abs(one)))
        one = np.roll(one, -n0)
        phases = np.mod(phases + 2.0 * np.pi * bins * n0 / n_per, 2.0 * np.pi)
    peak = float(np.max(np.abs(one)))
    scale = amplitude if amplitude_definition == "per_line" else (amplitude / peak if peak > 0 else 0.0)
    one = one * scale
    x = np.tile(one, periods)
    t = np.arange(x.size, dtype=np.float64) / fs_hz
    return Multisine(
        t=t,
        x=x,
        lines_hz=bins * (fs_hz / n_per),
        samples_per_period=n_per,
        lines_bins=bins,
        phases_rad=phases,
        line_amplitude=scale,
        fs_hz=fs_hz,
        periods=float(periods),
    )


# ---------------------------------------------------------------------------------------------
# sweep
# ---------------------------------------------------------------------------------------------
def _sweep_args(f_start_hz, f_stop_hz, sweep_duration_s, law):
    f_start_hz = _real("f_start_hz", f_start_hz, nonneg=True)
    f_stop_hz = _real("f_stop_hz", f_stop_hz, nonneg=True)
    sweep_duration_s = _real("sweep_duration_s", sweep_duration_s, positive=True)
    if law not in _SWEEP_LAWS:
        raise ValueError(f"law must be one of {_SWEEP_LAWS}, got {law!r}")
    if law == "log" and (f_start_hz <= 0.0 or f_stop_hz <= 0.0):
        raise ValueError(
            f"law='log' needs f_start_hz > 0 and f_stop_hz > 0, got {f_start_hz!r}, {f_stop_hz!r}"
        )
    return f_start_hz, f_stop_hz, sweep_duration_s


def sweep_frequency_at(t: np.ndarray | float, f_start_hz: float, f_stop_hz: float, sweep_duration_s: float,
                       law: str = "linear") -> np.ndarray | float:
    r"""Instantaneous frequency (Hz) of :func:`sweep` at time(s) ``t`` (s).

    .. math:: f(t) = f_0 + (f_1 - f_0)\,\tau \quad\text{(linear)},\qquad
              f(t) = f_0\,(f_1/f_0)^{\tau} \quad\text{(log)},\qquad
              \tau = \min(\max(t, 0), T)/T,

    i.e. ``f_start_hz`` before the sweep starts and ``f_stop_hz`` after ``sweep_duration_s``
    (the sweep holds its final frequency). Use it to report the frequency at which the rotor
    delevitates (paper Fig. 9). Returns a float for a scalar ``t``.
    """
    f0, f1, T = _sweep_args(f_start_hz, f_stop_hz, sweep_duration_s, law)
    tt = np.asarray(t, dtype=np.float64)
    tau = np.clip(tt, 0.0, T) / T
    if law == "linear":
        f = f0 + (f1 - f0) * tau
    else:
        f = f0 * (f1 / f0) ** tau
    return float(f) if np.ndim(t) == 0 else f


def sweep_phase_rad(
    t: np.ndarray | float,
    f_start_hz: float,
    f_stop_hz: float,
    sweep_duration_s: float,
    law: str = "linear",
) -> np.ndarray | float:
    r"""Phase :math:`\psi(t) = 2\pi \int_0^t f(s)\,ds` (rad) of :func:`sweep`, closed form.

    Linear: :math:`2\pi(f_0 t + (f_1 - f_0) t^2 / 2T)`; log:
    :math:`2\pi f_0 T (r^{t/T} - 1)/\ln r` with :math:`r = f_1/f_0` (the linear law when
    :math:`r = 1`); for :math:`t > T` the phase grows at :math:`2\pi f_1`, for :math:`t < 0`
    at :math:`2\pi f_0`. Continuous in ``t`` with continuous derivative.
    """
    f0, f1, T = _sweep_args(f_start_hz, f_stop_hz, sweep_duration_s, law)
    tt = np.asarray(t, dtype=np.float64)
    tc = np.clip(tt, 0.0, T)
    if law == "linear" or abs(math.log(f1 / f0)) < 1e-12:
        psi = f0 * tc + (f1 - f0) * tc**2 / (2.0 * T)
        psi_T = f0 * T + (f1 - f0) * T / 2.0
    else:
        lr = math.log(f1 / f0)
        psi = f0 * T * np.expm1(lr * tc / T) / lr
        psi_T = f0 * T * (f1 / f0 - 1.0) / lr
    psi = np.where(tt > T, psi_T + f1 * (tt - T), psi)
    psi = np.where(tt < 0.0, f0 * tt, psi)
    out = 2.0 * np.pi * psi
    return float(out) if np.ndim(t) == 0 else out


def sweep(
    fs_hz: float,
    duration_s: float,
    amplitude: float,
    f_start_hz: float,
    f_stop_hz: float,
    sweep_duration_s: float,
    law: str = "linear",
) -> np.ndarray:
    r"""Constant-amplitude, phase-continuous sine sweep (chirp).

    .. math:: x(t) = a \sin\psi(t), \qquad \psi(t) = 2\pi\int_0^t f(s)\,ds,

    with the instantaneous frequency :math:`f(t)` of :func:`sweep_frequency_at` going from
    ``f_start_hz`` to ``f_stop_hz`` over ``sweep_duration_s`` (linearly or geometrically) and
    holding ``f_stop_hz`` afterwards if ``duration_s`` is longer. The sine starts at zero
    (no jump of the reference at t = 0). The paper's validation sweep (section 6.2) is
    ``amplitude = 99e-6`` m, 11 Hz to 50 Hz.

    Returns
    -------
    numpy.ndarray
        float64 samples at ``t = n / fs_hz``.
    """
    fs_hz = _real("fs_hz", fs_hz, positive=True)
    amplitude = _real("amplitude", amplitude, nonneg=True)
    f0, f1, T = _sweep_args(f_start_hz, f_stop_hz, sweep_duration_s, law)
    if max(f0, f1) >= fs_hz / 2.0:
        raise ValueError(
            f"f_start_hz={f0!r} and f_stop_hz={f1!r} must be below the Nyquist frequency "
            f"fs_hz/2={fs_hz / 2!r}"
        )
    t = time_vector(fs_hz, duration_s)
    return amplitude * np.sin(sweep_phase_rad(t, f0, f1, T, law))


# ---------------------------------------------------------------------------------------------
# step
# ---------------------------------------------------------------------------------------------
def step(fs_hz: float, duration_s: float, amplitude: float, t_step_s: float) -> np.ndarray:
    """Step of height ``amplitude`` at ``t_step_s``: ``x[n] = amplitude`` for ``n/fs >= t_step_s``
    (to 1e-9 of a sample), 0 before.
    """
    fs_hz = _real("fs_hz", fs_hz, positive=True)
    amplitude = _real("amplitude", amplitude)
    t_step_s = _real("t_step_s", t_step_s, nonneg=True)
    n = n_samples(fs_hz, duration_s)
    n_step = math.ceil(t_step_s * fs_hz - 1e-9)
    x = np.zeros(n, dtype=np.float64)
    x[min(n_step, n):] = amplitude
    return x


# ---------------------------------------------------------------------------------------------
# from a spec dictionary
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Excitation:
    """An excitation built by :func:`make_excitation`.

    Attributes
    ----------
    t, x : numpy.ndarray
        Sample instants (s) and samples (``unit``).
    kind : str
        ``none``, ``pulses``, ``multisine``, ``sweep`` or ``step``.
    amplitude : float
        The spec's ``amplitude_m`` or ``amplitude_a`` (0 for ``none``).
    unit : str
        ``"m"``, ``"A"`` or ``""`` (for ``none``).
    seed : int or None
        The seed actually used (``None`` for deterministic kinds).
    params : dict
        The normalised parameters (for the ``meta`` JSON of a data file).
    multisine : Multisine or None
        For ``kind == "multisine"``: the full description (lines, bins, samples per period).
    """

    t: np.ndarray
    x: np.ndarray
    kind: str
    amplitude: float
    unit: str
    seed: int | None
    params: dict = field(default_factory=dict)
    multisine: Multisine | None = None

    @property
    def fs_hz(self) -> float:
        return float(self.params["fs_hz"])


_REQUIRED = {
    "none": (),
    "pulses": ("min_width_s", "max_width_s"),
    "multisine": ("f_min_hz", "f_max_hz", "periods"),
    "sweep": ("f_start_hz", "f_stop_hz", "sweep_duration_s"),
    "step": ("t_step_s",),
}
_OPTIONAL = {
    "none": (),
    "pulses": (),
    "multisine": ("f_resolution_hz", "phase", "amplitude_definition"),
    "sweep": ("law",),
    "step": (),
}
#: keys every spec may carry that this module does not use (where to inject, which axis, a
#: free description); ``seed`` and ``seed_offset`` are used, see :func:`make_excitation`.
_PASSTHROUGH = ("kind", "point", "axis", "seed", "seed_offset", "description", "name")


def _get(spec: Mapping, key: str, kind: str):
    if key not in spec or spec[key] is None:
        raise ValueError(f"excitation key '{key}': missing (required for kind '{kind}')")
    return spec[key]


def make_excitation(
    spec: Mapping[str, Any],
    fs_hz: float,
    duration_s: float | None,
    seed: int | None = None,
) -> Excitation:
    """Build an excitation from a spec dictionary (a ``config.yaml`` experiment or scenario).

    Examples of specs::

        {kind: multisine, amplitude_m: 1e-4, f_min_hz: 5, f_max_hz: 26, f_resolution_hz: 1, periods: 4}
        {kind: pulses, amplitude_a: 0.3, min_width_s: 2e-4, max_width_s: 4e-3}
        {kind: sweep, amplitude_m: 99e-6, f_start_hz: 11, f_stop_hz: 50, sweep_duration_s: 0.3, law: linear}
        {kind: step, amplitude_m: 1e-5, t_step_s: 0.01}
        {kind: none}

    Rules:

    * the amplitude is ``amplitude_m`` (position reference, m) or ``amplitude_a`` (current
      injection, A), exactly one of them (``none`` needs neither);
    * optional keys and defaults: multisine ``f_resolution_hz`` = 1.0 Hz (the rig scenario
      format omits it), ``phase`` = ``random``; sweep ``law`` = ``linear``;
    * ``point``, ``axis``, ``description`` and ``name`` are ignored here (the simulator uses
      them); any other unknown key is an error (a misspelt optional key would otherwise be
      silently replaced by its default);
    * the seed used is ``spec["seed"]`` if present, else the ``seed`` argument, plus
      ``spec["seed_offset"]`` if present (so a workflow passes the global ``config.seed`` and the
      experiment's ``seed_offset`` selects its own stream); random kinds need one;
    * ``duration_s`` may be ``None`` only for a multisine (then ``periods`` whole periods) and a
      sweep (then ``sweep_duration_s``). A multisine with an explicit ``duration_s`` is the
      periodic signal cut or repeated to that length.

    Raises
    ------
    ValueError
        Unknown ``kind``, a missing or unknown key (named in the message), or a bad value.
    """
    kind = _check_spec(spec)
    fs_hz = _real("fs_hz", fs_hz, positive=True)
    amplitude, unit = _amplitude(spec, kind)
    used_seed = _used_seed(spec, seed, kind)
    if duration_s is not None:
        duration_s = _real("duration_s", duration_s, positive=True)
    elif kind in ("none", "pulses", "step"):
        raise ValueError(f"duration_s: required for kind '{kind}'")
    _check_length(kind, spec, fs_hz, duration_s)
    params: dict[str, Any] = {"kind": kind, "fs_hz": fs_hz}
    t, x, ms = _BUILDERS[kind](spec, fs_hz, duration_s, amplitude, used_seed, params)
    params["duration_s"] = x.size / fs_hz
    if kind != "none":
        params["amplitude"] = amplitude
        params["unit"] = unit
    if used_seed is not None:
        params["seed"] = used_seed
    return Excitation(t=t, x=x, kind=kind, amplitude=amplitude, unit=unit, seed=used_seed,
                      params=params, multisine=ms)


#: the longest excitation built (samples): 20 minutes at 83.3 kHz. A simulation keeps every sample
#: of some 50 signals in memory (about 400 bytes per sample, 40 GB at this length), so a longer
#: one is a unit error or a resource bomb; the limit is checked before anything is allocated.
MAX_SAMPLES = 10**8


def _check_length(kind: str, spec: Mapping, fs_hz: float, duration_s: float | None) -> None:
    """Raise ValueError naming the key when the excitation would exceed :data:`MAX_SAMPLES`
    (``duration_s``, a multisine's period ``fs_hz / f_resolution_hz`` and its ``periods``, a
    sweep's ``sweep_duration_s``), before any array is allocated."""
    def num(key, default=None):
        v = spec.get(key, default)
        ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(float(v)) and float(v) > 0
        return float(v) if ok else None

    checks = []
    if duration_s is not None:
        checks.append(("duration_s", f"{duration_s:g} s", duration_s * fs_hz))
    if kind == "multisine" and num("f_resolution_hz", 1.0) is not None:
        n_per = fs_hz / num("f_resolution_hz", 1.0)
        checks.append(("excitation key 'f_resolution_hz'", f"one period of 1/{num('f_resolution_hz', 1.0):g} s", n_per))
        if duration_s is None and num("periods") is not None:
            checks.append(("excitation key 'periods'", f"{num('periods'):g} periods", num("periods") * n_per))
    if kind == "sweep" and duration_s is None and num("sweep_duration_s") is not None:
        checks.append(("excitation key 'sweep_duration_s'", f"{num('sweep_duration_s'):g} s",
                       num("sweep_duration_s") * fs_hz))
    for name, what, n in checks:
        if n > MAX_SAMPLES:
            raise ValueError(f"{name}: {what} at {fs_hz:g} Hz is {n:.3g} samples, more than the {MAX_SAMPLES:.0e} "
                             "a simulation can hold (it keeps every sample in memory, about 400 bytes each)")


def _check_spec(spec) -> str:
    """The spec's kind, after checking that every key is known for it."""
    if not isinstance(spec, Mapping):
        raise ValueError(f"excitation spec must be a mapping, got {type(spec).__name__}")
    if "kind" not in spec:
        raise ValueError("excitation key 'kind': missing (one of none, pulses, multisine, sweep, step)")
    kind = spec["kind"]
    if kind not in _REQUIRED:
        raise ValueError(
            f"excitation key 'kind': unknown kind {kind!r} (one of none, pulses, multisine, sweep, step)"
        )
    allowed = set(_PASSTHROUGH) | set(_REQUIRED[kind]) | set(_OPTIONAL[kind]) | {"amplitude_m", "amplitude_a"}
    unknown = sorted(str(k) for k in spec if k not in allowed)
    if unknown:
        raise ValueError(
            f"excitation key '{unknown[0]}': unknown for kind '{kind}' (allowed: {sorted(allowed)})"
        )
    return kind


def _amplitude(spec, kind: str) -> tuple[float, str]:
    """``(amplitude, unit)``: ``amplitude_m`` (m) or ``amplitude_a`` (A), exactly one."""
    if kind == "none":
        return 0.0, ""
    has_m = spec.get("amplitude_m") is not None
    has_a = spec.get("amplitude_a") is not None
    if has_m and has_a:
        raise ValueError("excitation keys 'amplitude_m' and 'amplitude_a': give only one of them")
    if not (has_m or has_a):
        raise ValueError(f"excitation key 'amplitude_m' (or 'amplitude_a'): missing (required for kind '{kind}')")
    key = "amplitude_m" if has_m else "amplitude_a"
    return _real(f"excitation key '{key}'", spec[key], nonneg=True), ("m" if has_m else "A")


def _used_seed(spec, seed, kind: str) -> int | None:
    """``spec['seed']`` (else ``seed``) plus ``spec['seed_offset']`` for the random kinds."""
    if not (kind == "pulses" or (kind == "multisine" and spec.get("phase", "random") == "random")):
        return None
    base = spec.get("seed", seed)
    if base is None:
        raise ValueError(f"excitation key 'seed': missing (kind '{kind}' is random: pass seed= or put seed in the "
                         "spec)")
    return _int("seed", base, minimum=0) + _int("excitation key 'seed_offset'", spec.get("seed_offset", 0), minimum=0)


def _build_none(spec, fs_hz, duration_s, amplitude, seed, params):
    t = time_vector(fs_hz, duration_s)
    return t, np.zeros_like(t), None


def _build_pulses(spec, fs_hz, duration_s, amplitude, seed, params):
    mn = _real("excitation key 'min_width_s'", _get(spec, "min_width_s", "pulses"), positive=True)
    mx = _real("excitation key 'max_width_s'", _get(spec, "max_width_s", "pulses"), positive=True)
    x = pulses(fs_hz, duration_s, amplitude, mn, mx, seed)
    params.update(min_width_s=mn, max_width_s=mx)
    return np.arange(x.size, dtype=np.float64) / fs_hz, x, None


def _build_multisine(spec, fs_hz, duration_s, amplitude, seed, params):
    fmin, fmax = _get(spec, "f_min_hz", "multisine"), _get(spec, "f_max_hz", "multisine")
    per = _int("excitation key 'periods'", _get(spec, "periods", "multisine"), minimum=1)
    fres = spec.get("f_resolution_hz", 1.0)
    phase, adef = spec.get("phase", "random"), spec.get("amplitude_definition", "peak")
    n_per = _samples_per_period(fs_hz, _real("excitation key 'f_resolution_hz'", fres, positive=True))
    needed = per if duration_s is None else max(1, math.ceil(n_samples(fs_hz, duration_s) / n_per))
    ms = multisine(fs_hz, amplitude, fmin, fmax, fres, needed, seed if seed is not None else 0, phase=phase,
                   amplitude_definition=adef)
    if duration_s is not None:
        n = n_samples(fs_hz, duration_s)
        ms = Multisine(t=ms.t[:n], x=ms.x[:n], lines_hz=ms.lines_hz, samples_per_period=ms.samples_per_period,
                       lines_bins=ms.lines_bins, phases_rad=ms.phases_rad, line_amplitude=ms.line_amplitude,
                       fs_hz=ms.fs_hz, periods=n / ms.samples_per_period)
    params.update(f_min_hz=float(fmin), f_max_hz=float(fmax), f_resolution_hz=float(fres), periods=ms.periods,
                  phase=phase, samples_per_period=ms.samples_per_period)
    if adef != "peak":
        params["amplitude_definition"] = adef
    return ms.t, ms.x, ms


def _build_sweep(spec, fs_hz, duration_s, amplitude, seed, params):
    f0, f1 = _get(spec, "f_start_hz", "sweep"), _get(spec, "f_stop_hz", "sweep")
    T = _get(spec, "sweep_duration_s", "sweep")
    law = spec.get("law", "linear")
    if duration_s is None:
        duration_s = _real("excitation key 'sweep_duration_s'", T, positive=True)
    x = sweep(fs_hz, duration_s, amplitude, f0, f1, T, law)
    params.update(f_start_hz=float(f0), f_stop_hz=float(f1), sweep_duration_s=float(T), law=law)
    return np.arange(x.size, dtype=np.float64) / fs_hz, x, None


def _build_step(spec, fs_hz, duration_s, amplitude, seed, params):
    ts = _get(spec, "t_step_s", "step")
    x = step(fs_hz, duration_s, amplitude, ts)
    params.update(t_step_s=float(ts))
    return np.arange(x.size, dtype=np.float64) / fs_hz, x, None


_BUILDERS = {"none": _build_none, "pulses": _build_pulses, "multisine": _build_multisine,
             "sweep": _build_sweep, "step": _build_step}
