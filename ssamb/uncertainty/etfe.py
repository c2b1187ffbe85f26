r"""Line spectra, ETFE and the additive mismatch of eq. (6) (paper section 5)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LineSpectra:
    r"""DFT of a periodic record at the excited lines.

    Attributes
    ----------
    lines_bins : numpy.ndarray
        DFT bins (over one period) of the lines.
    per_period : numpy.ndarray
        Complex line amplitudes of each steady-state period, shape ``(P, L)``:
        :math:`X_p(k) = \frac{2}{N}\sum_{n=0}^{N-1} x[pN + n]\,e^{-j2\pi kn/N}` (a cosine of
        amplitude :math:`a` and phase :math:`\varphi` gives :math:`a e^{j\varphi}`).
    mean : numpy.ndarray
        :math:`\hat X(k) = \frac1P \sum_p X_p(k)`, shape ``(L,)``.
    var : numpy.ndarray
        Between-period sample variance :math:`\hat\sigma^2_X(k) = \frac{1}{P-1}\sum_p
        |X_p(k) - \hat X(k)|^2` (NaN when ``P < 2``): the noise (and non-periodic distortion)
        level of one period.
    n_periods_used : int
        ``P``.
    """

    lines_bins: np.ndarray
    per_period: np.ndarray
    mean: np.ndarray
    var: np.ndarray
    n_periods_used: int

    @property
    def var_mean(self) -> np.ndarray:
        """Variance of :attr:`mean`, :math:`\\hat\\sigma^2_X / P`."""
        return self.var / self.n_periods_used


def _as_1d(name: str, a) -> np.ndarray:
    x = np.asarray(a, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array (one SISO channel), got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} contains non-finite samples")
    return x


def _bins(lines_bins, samples_per_period: int) -> np.ndarray:
    b = np.asarray(lines_bins)
    if b.ndim != 1 or b.size == 0:
        raise ValueError("lines_bins must be a non-empty 1-D array of DFT bins")
    if not np.all(np.asarray(b, dtype=np.float64) == np.round(np.asarray(b, dtype=np.float64))):
        raise ValueError("lines_bins must hold whole DFT bin numbers")
    b = b.astype(np.int64)
    if np.any(b < 1) or np.any(b > samples_per_period // 2):
        raise ValueError(
            f"lines_bins must lie in [1, samples_per_period/2 = {samples_per_period // 2}]"
        )
    return b


def line_spectra(
    signal,
    samples_per_period: int,
    n_periods: int | None,
    lines_bins,
    *,
    n_transient_periods: int = 1,
) -> LineSpectra:
    """DFT at the excited lines of each steady-state period, averaged over the periods.

    Parameters
    ----------
    signal : array_like, 1-D
        A record that starts at a period boundary of the periodic excitation.
    samples_per_period : int
        ``N`` (:attr:`ssamb.signals.Multisine.samples_per_period`).
    n_periods : int or None
        Number of whole periods of ``signal`` to consider, counted from its start (``None``: all
        whole periods it holds). Samples after them are ignored.
    lines_bins : array_like of int
        Excited DFT bins (:attr:`ssamb.signals.Multisine.lines_bins`).
    n_transient_periods : int
        Leading periods discarded as transient (default 1). At least one period must remain.

    Returns
    -------
    LineSpectra
    """
    x = _as_1d("signal", signal)
    n = int(samples_per_period)
    if n < 2 or n != samples_per_period:
        raise ValueError(f"samples_per_period must be an integer >= 2, got {samples_per_period!r}")
    bins = _bins(lines_bins, n)
    available = x.size // n
    if n_periods is None:
        n_periods = available
    n_periods = int(n_periods)
    if n_periods > available:
        raise ValueError(
            f"n_periods={n_periods} but the signal holds only {available} whole periods of "
            f"{n} samples ({x.size} samples)"
        )
    if n_transient_periods < 0:
        raise ValueError(f"n_transient_periods must be >= 0, got {n_transient_periods}")
    used = n_periods - int(n_transient_periods)
    if used < 1:
        raise ValueError(
            f"no steady-state period left: n_periods={n_periods}, n_transient_periods="
            f"{n_transient_periods}"
        )
    seg = x[n_transient_periods * n: n_periods * n].reshape(used, n)
    spec = np.fft.rfft(seg, axis=1)[:, bins] * (2.0 / n)
    mean = spec.mean(axis=0)
    if used >= 2:
        var = np.sum(np.abs(spec - mean) ** 2, axis=0) / (used - 1)
    else:
        var = np.full(bins.size, np.nan)
    return LineSpectra(lines_bins=bins, per_period=spec, mean=mean, var=var, n_periods_used=used)


# =============================================================================================
# 2. ETFE and additive mismatch
# =============================================================================================
@dataclass(frozen=True)
class Etfe:
    r"""Empirical transfer function estimate :math:`\hat G = \hat Y/\hat X` at the lines.

    Attributes
    ----------
    freqs_hz : numpy.ndarray
        Line frequencies (Hz).
    g : numpy.ndarray
        Complex ETFE.
    std : numpy.ndarray
        Standard deviation of :attr:`g` from the period-to-period spread (NaN with one period).
    u, y : LineSpectra
        Input and output line spectra.
    """

    freqs_hz: np.ndarray
    g: np.ndarray
    std: np.ndarray
    u: LineSpectra
    y: LineSpectra

    @property
    def mag(self) -> np.ndarray:
        return np.abs(self.g)


def _ratio_std(u: LineSpectra, y: LineSpectra, g: np.ndarray) -> np.ndarray:
    """First-order (delta-method) standard deviation of :math:`\\hat Y/\\hat X`.

    .. math:: \\sigma^2_G = \\frac{|G|^2}{P}\\left(\\frac{\\sigma_Y^2}{|Y|^2} +
              \\frac{\\sigma_X^2}{|X|^2} - 2\\,\\mathrm{Re}\\frac{\\sigma_{YX}^2}{Y X^*}\\right)

    with the sample (co)variances over the ``P`` periods (Pintelon and Schoukens, *System
    Identification: A Frequency Domain Approach*, 2nd ed., section 2.4).
    """
    p = u.n_periods_used
    if p < 2:
        return np.full(g.shape, np.nan)
    du = u.per_period - u.mean
    dy = y.per_period - y.mean
    cov_yu = np.sum(dy * np.conj(du), axis=0) / (p - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = (
            y.var / np.abs(y.mean) ** 2
            + u.var / np.abs(u.mean) ** 2
            - 2.0 * np.real(cov_yu / (y.mean * np.conj(u.mean)))
        )
        var = np.abs(g) ** 2 * np.maximum(rel, 0.0) / p
    return np.sqrt(var)


def etfe(
    u,
    y,
    *,
    fs_hz: float,
    samples_per_period: int,
    lines_bins,
    n_periods: int | None = None,
    n_transient_periods: int = 1,
) -> Etfe:
    r"""ETFE :math:`\hat G(k) = \hat Y(k) / \hat X(k)` of a SISO channel at the excited lines.

    ``u`` and ``y`` are the input and output samples of the subsystem (1-D, same length, same
    start) recorded while a periodic excitation with ``samples_per_period`` samples per period
    and lines ``lines_bins`` drives the loop. Spectra are averaged over the steady-state periods
    before the division (errors-in-variables robust for output noise), see
    :func:`line_spectra`. For an LTI system in periodic steady state the estimate equals the
    frequency response at the lines exactly (``G(e^{j2\pi k/N})`` for a discrete-time system).

    MIMO subsystems: the caller passes one input and one output channel. In closed loop with a
    single excitation, :math:`Y_i/X_j` is the *apparent* SISO transfer from input ``j`` to output
    ``i`` along the direction the experiment excites (it includes what the other inputs
    contribute, since they are correlated with ``X_j``); separating a full matrix needs as many
    independent experiments as inputs. The paper uses the SISO self-sensing channel (coil
    current -> y position estimate) for Fig. 7.

    Returns
    -------
    Etfe
    """
    u_ = _as_1d("u", u)
    y_ = _as_1d("y", y)
    if u_.size != y_.size:
        raise ValueError(f"u and y must have the same length, got {u_.size} and {y_.size}")
    fs_hz = float(fs_hz)
    if not (fs_hz > 0 and math.isfinite(fs_hz)):
        raise ValueError(f"fs_hz must be > 0, got {fs_hz!r}")
    su = line_spectra(u_, samples_per_period, n_periods, lines_bins, n_transient_periods=n_transient_periods)
    sy = line_spectra(y_, samples_per_period, n_periods, lines_bins, n_transient_periods=n_transient_periods)
    if np.any(su.mean == 0):
        raise ValueError("the input u has no component on some excited line: the ETFE is undefined there")
    g = sy.mean / su.mean
    freqs = su.lines_bins * (fs_hz / int(samples_per_period))
    return Etfe(freqs_hz=freqs, g=g, std=_ratio_std(su, sy, g), u=su, y=sy)


@dataclass(frozen=True)
class Mismatch:
    r"""Additive mismatch :math:`\hat\Delta_a = Y/X - \bar Y/\bar X` at the lines (eq. 6).

    Attributes
    ----------
    freqs_hz : numpy.ndarray
        Line frequencies (Hz).
    delta : numpy.ndarray
        Complex mismatch.
    std : numpy.ndarray
        Its standard deviation, :math:`\sqrt{\sigma^2_{real} + \sigma^2_{model}}` (the two
        records are independent).
    real, model : Etfe
        The two ETFEs.
    """

    freqs_hz: np.ndarray
    delta: np.ndarray
    std: np.ndarray
    real: Etfe
    model: Etfe

    @property
    def mag(self) -> np.ndarray:
        """:math:`|\\hat\\Delta_a|`, the right-hand side of eq. (6)."""
        return np.abs(self.delta)

    def upper(self, k_sigma: float = 2.0) -> np.ndarray:
        """A noise-aware bound :math:`|\\hat\\Delta_a| + k\\sigma` (NaN std counts as 0)."""
        return self.mag + k_sigma * np.nan_to_num(self.std, nan=0.0)


def additive_mismatch(
    u_real,
    y_real,
    u_model,
    y_model,
    *,
    fs_hz: float,
    samples_per_period: int,
    lines_bins,
    n_periods: int | None = None,
    n_transient_periods: int = 1,
) -> Mismatch:
    r"""Additive mismatch :math:`Y/X - \bar Y/\bar X` on the excited lines (paper eq. 6).

    ``(u_real, y_real)`` are the subsystem's input and output in the nonlinear simulation (or the
    rig), ``(u_model, y_model)`` the same signals in the closed-loop LTI model, both records
    driven by multisines with the same period and lines (they need not be the same realisation:
    the comparison is in the frequency domain, section 5). Records may differ in length;
    ``n_periods=None`` uses every whole period of each. See :func:`etfe` for MIMO subsystems.

    Returns
    -------
    Mismatch
    """
    kw = dict(fs_hz=fs_hz, samples_per_period=samples_per_period, lines_bins=lines_bins,
              n_periods=n_periods, n_transient_periods=n_transient_periods)
    real = etfe(u_real, y_real, **kw)
    model = etfe(u_model, y_model, **kw)
    delta = real.g - model.g
    std = np.sqrt(real.std**2 + model.std**2)
    return Mismatch(freqs_hz=real.freqs_hz, delta=delta, std=std, real=real, model=model)
