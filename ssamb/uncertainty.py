r"""Additive dynamic uncertainty: ETFE of the mismatch (eq. 6), peak envelope, weight fit (Fig. 7).

Paper section 5 (/work/shared/seed-paper.md) models what the nominal LTI model misses as an
additive uncertainty :math:`G = \bar G + W\Delta`, :math:`\|\Delta\|_\infty \le 1` (eq. 4), and
measures its size with the empirical transfer function estimate (ETFE) of eq. (6):

.. math:: |W(j\omega)| \;\ge\; \left|\frac{Y(j\omega)}{X(j\omega)} -
          \frac{\bar Y(j\omega)}{\bar X(j\omega)}\right|,

where :math:`X, Y` are the input and output spectra of one subsystem inside the nonlinear
("real") closed loop and :math:`\bar X, \bar Y` the same signals in the closed-loop LTI model,
both driven at the system input by the same random-phase multisine reference (5-26 Hz,
100 um). The steps here are

1. :func:`line_spectra` -- DFT of each steady-state period at the excited lines, averaged, with
   the period-to-period variance as a noise estimate;
2. :func:`etfe` and :func:`additive_mismatch` -- :math:`Y/X`, and
   :math:`Y/X - \bar Y/\bar X` with a per-line standard deviation;
3. :func:`peak_envelope` -- a smooth upper envelope through the peaks of :math:`|Y/X - \bar
   Y/\bar X|` ("finding a number of peaks in the ETFE and connect them with low order curves");
4. :func:`fit_weight` -- a stable, minimum-phase, strictly proper :math:`W(s)` with real poles
   and zeros placed by first-order asymptotic Bode approximations and refined, within
   ``tol_db`` (3 dB in the paper) of the envelope on the measured band and above the ETFE on
   every line;
5. :func:`plot_weight` -- the Fig. 7 equivalent.

Conventions: frequencies in Hz (``freqs_hz``), :math:`s = j 2\pi f` in rad/s for the transfer
functions, magnitudes in the unit of the mismatch (output unit per input unit, e.g. m/A for the
self-sensing module whose input is a coil current and output a position estimate), dB is
:math:`20\log_{10}`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.optimize
import scipy.sparse

__all__ = [
    "LineSpectra",
    "Etfe",
    "Mismatch",
    "Envelope",
    "WeightFit",
    "line_spectra",
    "etfe",
    "additive_mismatch",
    "peak_envelope",
    "fit_weight",
    "weight_db",
    "plot_weight",
]

_DB = 20.0
_LN10 = math.log(10.0)


# =============================================================================================
# 1. line spectra
# =============================================================================================
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


# =============================================================================================
# 3. envelope
# =============================================================================================
def _check_freq_mag(freqs_hz, mag, what: str = "mag") -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(freqs_hz, dtype=np.float64)
    m = np.asarray(mag, dtype=np.float64)
    if f.ndim != 1 or m.ndim != 1:
        raise ValueError(f"freqs_hz and {what} must be 1-D arrays")
    if f.size == 0:
        raise ValueError(f"the ETFE is empty: freqs_hz and {what} have no points")
    if f.size != m.size:
        raise ValueError(f"freqs_hz and {what} must have the same length, got {f.size} and {m.size}")
    if not np.all(np.isfinite(f)):
        raise ValueError("freqs_hz contains non-finite values")
    if np.any(f <= 0):
        raise ValueError("freqs_hz must be > 0 (a log-frequency fit)")
    if np.any(np.diff(f) <= 0):
        raise ValueError("freqs_hz must be strictly increasing")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{what} contains non-finite values (NaN or inf)")
    if np.any(m < 0):
        raise ValueError(f"{what} must be >= 0 (a magnitude)")
    if not np.any(m > 0):
        raise ValueError(f"{what} is identically zero: there is no mismatch to bound")
    return f, m


def _check_extension(extension: str) -> str:
    if extension not in ("hold", "smooth"):
        raise ValueError(f"extension must be 'hold' or 'smooth', got {extension!r}")
    return extension


def _to_db(m: np.ndarray) -> np.ndarray:
    floor = np.max(m) * 1e-12  # zeros become -240 dB below the largest value
    return _DB * np.log10(np.maximum(m, floor))


@dataclass(frozen=True)
class Envelope:
    r"""Smooth upper envelope of an ETFE magnitude (see :func:`peak_envelope`).

    In the measured band :math:`[f_{lo}, f_{hi}]` the envelope is the piecewise-linear
    interpolation in (:math:`\log_{10} f`, dB) of dense nodes. Outside, where nothing was
    measured, it never assumes that the mismatch shrinks:

    * where the envelope *rises* away from the band (slope :math:`S` at the edge, in dB/decade,
      pointing outwards), it continues with that slope relaxing to zero at the curvature bound
      :math:`\kappa`, :math:`E = E_{edge} + S u - \kappa u^2/2` for
      :math:`0 \le u \le S/\kappa` decades from the edge, then stays flat at
      :math:`E_{edge} + S^2/2\kappa` (the smoothest continuation a real-pole weight can follow);
    * where it *falls* away from the band it stays flat at the edge level with
      ``extension="hold"`` (the default: the level measured at the edge is assumed to persist,
      a conservative choice), or falls with the same relaxing-slope continuation (mirror image
      of the rising case) with ``extension="smooth"`` (what a low-order weight does anyway);
    * with an infinite :math:`\kappa` both sides are flat at the edge levels;
    * above the band it is multiplied by the magnitude of one real pole at ``f_rolloff_hz``,
      normalised to 1 at :math:`f_{hi}`, :math:`|1 + jf_{hi}/f_{roll}| / |1 + jf/f_{roll}|`
      (falling at 20 dB/decade above ``f_rolloff_hz``: what a strictly proper weight must do
      eventually).

    Attributes
    ----------
    nodes_hz, nodes_db : numpy.ndarray
        Nodes of the in-band curve.
    freqs_hz, mag : numpy.ndarray
        The data it bounds.
    peaks_hz : numpy.ndarray
        The data frequencies where the envelope touches the data (the "peaks" it connects).
    f_rolloff_hz : float
        Start of the high-frequency roll-off.
    max_curvature_db_per_decade2 : float
        Curvature bound used (dB/decade^2).
    extension : str
        ``"hold"`` or ``"smooth"``, see above.
    """

    nodes_hz: np.ndarray
    nodes_db: np.ndarray
    freqs_hz: np.ndarray
    mag: np.ndarray
    peaks_hz: np.ndarray
    f_rolloff_hz: float
    max_curvature_db_per_decade2: float
    extension: str = "hold"

    @property
    def f_lo_hz(self) -> float:
        return float(self.nodes_hz[0])

    @property
    def f_hi_hz(self) -> float:
        return float(self.nodes_hz[-1])

    def _edge_slopes(self) -> tuple[float, float]:
        """Outward slopes (dB/decade) at the low and high band edges (positive: rising away)."""
        xn = np.log10(self.nodes_hz)
        if xn.size < 2 or xn[-1] - xn[0] <= 0:
            return 0.0, 0.0
        s_lo = (self.nodes_db[1] - self.nodes_db[0]) / (xn[1] - xn[0])
        s_hi = (self.nodes_db[-1] - self.nodes_db[-2]) / (xn[-1] - xn[-2])
        return float(-s_lo), float(s_hi)

    def db(self, freqs_hz) -> np.ndarray:
        """Envelope in dB at ``freqs_hz`` (any positive frequencies), extension included."""
        f = np.asarray(freqs_hz, dtype=np.float64)
        x = np.log10(f)
        xn = np.log10(self.nodes_hz)
        out = np.interp(x, xn, self.nodes_db)  # flat beyond both ends
        kappa = self.max_curvature_db_per_decade2
        if math.isfinite(kappa):
            for s_out, u in zip(self._edge_slopes(), (xn[0] - x, x - xn[-1])):
                if s_out > 0 or (self.extension == "smooth" and s_out < 0):
                    sgn = 1.0 if s_out > 0 else -1.0
                    uc = np.clip(u, 0.0, abs(s_out) / kappa)
                    out = out + np.where(u > 0, s_out * uc - sgn * 0.5 * kappa * uc**2, 0.0)
        fh = np.maximum(f, self.nodes_hz[-1]) / self.f_rolloff_hz
        ref = (self.nodes_hz[-1] / self.f_rolloff_hz) ** 2
        return out - 10.0 * np.log10((1.0 + fh**2) / (1.0 + ref))

    def __call__(self, freqs_hz) -> np.ndarray:
        """Envelope magnitude (linear) at ``freqs_hz``."""
        return 10.0 ** (self.db(freqs_hz) / _DB)

    @classmethod
    def from_samples(cls, freqs_hz, envelope_mag, *, f_rolloff_hz: float | None = None,
                     max_curvature_db_per_decade2: float = 60.0, extension: str = "hold") -> "Envelope":
        """An envelope given by its values at ``freqs_hz`` (log-log interpolation between them;
        ``max_curvature_db_per_decade2`` only shapes the extension outside the band)."""
        f, m = _check_freq_mag(freqs_hz, envelope_mag, "envelope_mag")
        if np.any(m <= 0):
            raise ValueError("envelope_mag must be > 0")
        roll = 10.0 * f[-1] if f_rolloff_hz is None else float(f_rolloff_hz)
        if not roll >= f[-1]:
            raise ValueError(f"f_rolloff_hz={roll!r} must be >= the last frequency {f[-1]!r}")
        return cls(nodes_hz=f, nodes_db=_DB * np.log10(m), freqs_hz=f, mag=m, peaks_hz=f.copy(),
                   f_rolloff_hz=roll, max_curvature_db_per_decade2=float(max_curvature_db_per_decade2),
                   extension=_check_extension(extension))


def peak_envelope(
    freqs_hz,
    mag,
    *,
    max_curvature_db_per_decade2: float = 60.0,
    nodes_per_decade: int = 200,
    f_rolloff_hz: float | None = None,
    extension: str = "hold",
) -> Envelope:
    r"""Smooth upper envelope through the peaks of an ETFE magnitude (paper section 5).

    The paper finds "a number of peaks in the ETFE and connect[s] them with low order curves".
    Here the envelope :math:`E(x)` (dB, over :math:`x = \log_{10} f`) is the solution of the
    linear program

    .. math:: \min_E \int_{x_{lo}}^{x_{hi}} E(x)\,dx \quad\text{s.t.}\quad
              E(x) \ge \hat y(x), \qquad |E''(x)| \le \kappa,

    where :math:`\hat y` is the data :math:`20\log_{10} m_i` joined by straight lines in
    log-log coordinates (so :math:`E(x_i) \ge 20\log_{10} m_i` and the envelope does not sag
    between lines), on a grid of nodes that contains every data frequency (second differences
    for :math:`E''`, solved with HiGHS). The solution touches the data at a subset of points (the
    *peaks*, returned in ``peaks_hz``) and connects them with arcs of constant curvature
    :math:`\pm\kappa` or straight lines in log-log coordinates -- the "low order curves". It lies
    on or above every measured magnitude (enforced exactly at the data points).

    Why a curvature bound: a real pole or zero changes the log-magnitude slope by 20 dB/decade
    over about half a decade, with a curvature of at most :math:`10\ln 10 \approx 23`
    dB/decade^2; a weight made of real poles and zeros cannot follow sharper bends within 3 dB.
    Bridging narrow dips and widening narrow spikes to :math:`\kappa` (default 60, i.e. up to
    about three coincident real corners) makes the envelope followable by :func:`fit_weight`
    while staying as close to the data as that allows. A larger ``max_curvature`` follows the
    data more tightly and needs a higher-order weight; ``inf`` gives the piecewise-linear
    interpolation of the data.

    Outside the measured band, where the mismatch is unmeasured, the envelope never assumes it
    shrinks (``extension="hold"``): where it rises towards a band edge it continues with its edge
    slope relaxing to zero at the curvature bound :math:`\kappa` and then stays flat; where it
    falls towards an edge it stays flat at the edge level. Above the band it is multiplied by
    one real pole at ``f_rolloff_hz`` (default ten times the highest line), the roll-off a
    strictly proper weight needs. See :class:`Envelope` (and
    ``extension="smooth"``).

    Parameters
    ----------
    freqs_hz : array_like
        Strictly increasing positive frequencies (Hz) of the ETFE lines.
    mag : array_like
        Non-negative magnitudes (zeros are floored 240 dB below the largest value).
    max_curvature_db_per_decade2 : float
        :math:`\kappa` (dB/decade^2), > 0.
    nodes_per_decade : int
        Density of the grid nodes between data points.
    f_rolloff_hz : float, optional
        Start of the high-frequency roll-off (>= the highest line).
    extension : {"hold", "smooth"}
        Continuation outside the band where the envelope falls towards an edge.

    Returns
    -------
    Envelope

    Raises
    ------
    ValueError
        Empty, non-finite or negative data, non-increasing frequencies, bad parameters.
    """
    f, m = _check_freq_mag(freqs_hz, mag)
    kappa = float(max_curvature_db_per_decade2)
    if not kappa > 0:
        raise ValueError(f"max_curvature_db_per_decade2 must be > 0, got {max_curvature_db_per_decade2!r}")
    if int(nodes_per_decade) != nodes_per_decade or nodes_per_decade < 1:
        raise ValueError(f"nodes_per_decade must be an integer >= 1, got {nodes_per_decade!r}")
    roll = 10.0 * f[-1] if f_rolloff_hz is None else float(f_rolloff_hz)
    if not roll >= f[-1]:
        raise ValueError(f"f_rolloff_hz={roll!r} must be >= the highest line {f[-1]!r}")
    y = _to_db(m)
    xd = np.log10(f)
    if f.size == 1 or not math.isfinite(kappa):
        nodes_x, e = xd, y.copy()
        if f.size == 1:
            nodes_x = np.array([xd[0], xd[0]])
            e = np.array([y[0], y[0]])
    else:
        h_max = 1.0 / float(nodes_per_decade)
        pieces = [xd[:1]]
        for a, b in zip(xd[:-1], xd[1:]):
            k = max(1, int(math.ceil((b - a) / h_max)))
            pieces.append(np.linspace(a, b, k + 1)[1:])
        nodes_x = np.concatenate(pieces)
        data_idx = np.searchsorted(nodes_x, xd)
        e = _envelope_lp(nodes_x, data_idx, y, kappa)
        e[data_idx] = np.maximum(e[data_idx], y)  # exactly on or above the data
    if f.size == 1:
        nodes_hz = np.array([f[0], f[0] * (1 + 1e-12)])
    else:
        nodes_hz = 10.0 ** nodes_x
        nodes_hz[0], nodes_hz[-1] = f[0], f[-1]
    at_data = np.interp(xd, np.log10(nodes_hz), e) if f.size > 1 else np.array([e[0]])
    peaks = f[at_data - y <= 1e-6 * max(1.0, float(np.max(np.abs(y))))]
    return Envelope(nodes_hz=nodes_hz, nodes_db=e, freqs_hz=f, mag=m, peaks_hz=peaks,
                    f_rolloff_hz=roll, max_curvature_db_per_decade2=kappa,
                    extension=_check_extension(extension))


def _envelope_lp(x: np.ndarray, data_idx: np.ndarray, y: np.ndarray, kappa: float) -> np.ndarray:
    n = x.size
    h = np.diff(x)
    # trapezoid weights of the integral
    w = np.zeros(n)
    w[:-1] += h / 2
    w[1:] += h / 2
    rows, cols, vals = [], [], []
    b = []
    r = 0
    # data: -E_k <= -y(x_k), y interpolated linearly (log-log) between the data points, so the
    # envelope does not sag between lines (at the data points this is E_i >= y_i)
    y_nodes = np.interp(x, x[data_idx], y)
    for k in range(n):
        rows.append(r); cols.append(k); vals.append(-1.0); b.append(-y_nodes[k]); r += 1
    # curvature: |(E_{k+1}-E_k)/h_k - (E_k-E_{k-1})/h_{k-1}| <= kappa (h_{k-1}+h_k)/2
    for k in range(1, n - 1):
        c_m, c_0, c_p = 1.0 / h[k - 1], -(1.0 / h[k - 1] + 1.0 / h[k]), 1.0 / h[k]
        lim = kappa * (h[k - 1] + h[k]) / 2.0
        for sgn in (1.0, -1.0):
            rows += [r, r, r]; cols += [k - 1, k, k + 1]
            vals += [sgn * c_m, sgn * c_0, sgn * c_p]
            b.append(lim); r += 1
    a_ub = scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(r, n))
    # shift the data to O(1) numbers for the solver
    y0 = float(np.max(y))
    b = np.asarray(b)
    b[:n] += y0
    res = scipy.optimize.linprog(w, A_ub=a_ub, b_ub=b, bounds=[(None, None)] * n, method="highs")
    if res.status != 0:  # pragma: no cover - the LP is always feasible and bounded
        raise RuntimeError(f"envelope LP failed: {res.message}")
    return res.x + y0


# =============================================================================================
# 4. weight fit
# =============================================================================================
def weight_db(freqs_hz, gain_db: float, zeros_hz: Sequence[float], poles_hz: Sequence[float]) -> np.ndarray:
    r""":math:`20\log_{10}|W(j2\pi f)|` of
    :math:`W(s) = K \prod_i (1 + s/\omega_{z,i}) / \prod_j (1 + s/\omega_{p,j})`,
    :math:`K = 10^{g/20}`, :math:`\omega = 2\pi f_{corner}`."""
    f = np.asarray(freqs_hz, dtype=np.float64)[:, None]
    z = np.asarray(zeros_hz, dtype=np.float64)[None, :]
    p = np.asarray(poles_hz, dtype=np.float64)[None, :]
    return (gain_db + 10.0 * np.sum(np.log10(1.0 + (f / z) ** 2), axis=1)
            - 10.0 * np.sum(np.log10(1.0 + (f / p) ** 2), axis=1))


@dataclass(frozen=True)
class WeightFit:
    r"""A fitted uncertainty weight (see :func:`fit_weight`).

    Attributes
    ----------
    W : control.TransferFunction
        :math:`W(s) = K\prod_i(1+s/\omega_{z,i})/\prod_j(1+s/\omega_{p,j})` (s in rad/s).
    W_ss : control.StateSpace
        The same weight as a cascade of first-order sections (triangular A, poles exactly
        :math:`-\omega_{p,j}`); prefer it for state-space work (LFTs, mu): the fit often puts
        several corners at one frequency, and the roots of a polynomial with a multiple root
        are ill-conditioned.
    gain : float
        DC gain :math:`K = W(0)` (unit of the mismatch).
    zeros_hz, poles_hz : numpy.ndarray
        Corner frequencies (Hz) of the real LHP zeros and poles (sorted).
    order : int
        Number of poles (strictly more than the number of zeros).
    max_dev_db : float
        :math:`\max |20\log_{10}|W| - E|` over the measured band (dense grid and the lines).
    within_tol : bool
        ``max_dev_db <= tol_db``.
    bound_holds : bool
        :math:`|W| \ge` ETFE magnitude on every line (eq. 6).
    min_margin_db : float
        :math:`\min_i (20\log_{10}|W(f_i)| - 20\log_{10} m_i)` (>= 0 when the bound holds).
    gain_raise_db : float
        Gain added in the last step to make the bound hold (0 if not needed).
    tol_db : float
        Requested tolerance.
    band_hz : tuple
        Measured band ``(f_lo, f_hi)``.
    envelope : Envelope
        The envelope fitted.
    history : list of dict
        Candidates tried: order, max deviation.
    """

    W: object
    W_ss: object
    gain: float
    zeros_hz: np.ndarray
    poles_hz: np.ndarray
    order: int
    max_dev_db: float
    within_tol: bool
    bound_holds: bool
    min_margin_db: float
    gain_raise_db: float
    tol_db: float
    band_hz: tuple
    envelope: Envelope
    history: list = field(default_factory=list)

    def db(self, freqs_hz) -> np.ndarray:
        """:math:`20\\log_{10}|W(j2\\pi f)|`."""
        return weight_db(freqs_hz, _DB * math.log10(self.gain), self.zeros_hz, self.poles_hz)

    def mag(self, freqs_hz) -> np.ndarray:
        """:math:`|W(j2\\pi f)|`."""
        return 10.0 ** (self.db(freqs_hz) / _DB)


# ------------------------------------------------------------------ stage 1: Bode asymptotes
def _asymptotic_corners(x: np.ndarray, target: np.ndarray, delta: float):
    """Place real corners so that the straight-line Bode asymptote tracks ``target`` within
    ``delta`` dB: walk up in frequency from a constant at the low-frequency level; when the
    target rises more than ``delta`` above the asymptote add a zero (slope +20 dB/decade),
    when it falls more than ``delta`` below add a pole (-20 dB/decade). The corner is put where
    the new asymptote passes through the target at the current point."""
    level = float(target[0])
    slope = 0.0
    zeros, poles = [], []
    last = x[0]
    a = level
    for k in range(1, x.size):
        a += slope * (x[k] - x[k - 1])
        e = target[k] - a
        guard = 0
        while abs(e) > delta and guard < 8:
            guard += 1
            xc = max(x[k] - abs(e) / 20.0, last)
            sgn = 1.0 if e > 0 else -1.0
            (zeros if sgn > 0 else poles).append(xc)
            a += sgn * 20.0 * (x[k] - xc)
            slope += sgn * 20.0
            last = xc
            e = target[k] - a
            if xc == x[k]:
                break
    return level, np.array(zeros), np.array(poles)


# ------------------------------------------------------------------ stage 2: refinement
class _Problem:
    """Minimax fit of the log-magnitude: min t + lam*mean(oob residual^2)/tol
    s.t. |L - E| <= t on the band grid, L >= data on the lines."""

    def __init__(self, xb, eb, xo, eo, xl, yl, tol, lam, xmin, xmax):
        self.fb, self.eb = 10.0 ** xb, eb
        self.fo, self.eo = 10.0 ** xo, eo
        self.fl, self.yl = 10.0 ** xl, yl
        self.tol, self.lam = tol, lam
        self.xmin, self.xmax = xmin, xmax

    @staticmethod
    def _lj(f, g, xz, xp):
        """log-magnitude and its Jacobian w.r.t. [g, xz..., xp...]."""
        rz = (f[:, None] / 10.0 ** xz[None, :]) ** 2
        rp = (f[:, None] / 10.0 ** xp[None, :]) ** 2
        val = g + 10.0 * np.log10(1.0 + rz).sum(1) - 10.0 * np.log10(1.0 + rp).sum(1)
        jac = np.empty((f.size, 1 + xz.size + xp.size))
        jac[:, 0] = 1.0
        jac[:, 1:1 + xz.size] = -20.0 * rz / (1.0 + rz)
        jac[:, 1 + xz.size:] = 20.0 * rp / (1.0 + rp)
        return val, jac

    @staticmethod
    def _spread(xc, step=0.03):
        """Separate coincident corners: their gradients are identical, so an optimiser would
        move them together forever (a symmetric saddle)."""
        xc = np.sort(np.asarray(xc, dtype=np.float64))
        for i in range(1, xc.size):
            if xc[i] - xc[i - 1] < step:
                xc[i] = xc[i - 1] + step
        return xc

    def solve(self, g, xz, xp, maxiter=300, band_limit=None):
        """Phase 1 (``band_limit=None``): minimise ``t`` = the largest in-band deviation (plus a
        light least-squares pull to the extension). Phase 2 (``band_limit`` given): minimise
        ``t`` = the largest deviation from the extension outside the band, with the in-band
        deviation kept below ``band_limit``. Both keep L >= data on the lines."""
        xz, xp = self._spread(xz), self._spread(xp)
        nz, npol = xz.size, xp.size
        split = lambda v: (v[0], v[1:1 + nz], v[1 + nz:1 + nz + npol])
        phase2 = band_limit is not None

        def obj(v):
            grad = np.zeros_like(v)
            grad[-1] = 1.0
            if phase2:
                return v[-1], grad
            g_, z_, p_ = split(v)
            lo, jo = self._lj(self.fo, g_, z_, p_)
            r = lo - self.eo
            grad[:-1] = self.lam * 2.0 * (r @ jo) / r.size / self.tol
            return v[-1] + self.lam * np.mean(r**2) / self.tol, grad

        def parts(v):
            g_, z_, p_ = split(v)
            lb, jb = self._lj(self.fb, g_, z_, p_)
            ll, jl = self._lj(self.fl, g_, z_, p_)
            lo, jo = self._lj(self.fo, g_, z_, p_) if phase2 else (None, None)
            return lb - self.eb, jb, ll - self.yl, jl, (lo - self.eo if phase2 else None), jo

        def cons(v):
            db, _, dl, _, do, _ = parts(v)
            if phase2:
                return np.concatenate([band_limit - db, band_limit + db, dl, v[-1] - do, v[-1] + do])
            return np.concatenate([v[-1] - db, v[-1] + db, dl])

        def cons_jac(v):
            _, jb, _, jl, _, jo = parts(v)
            zb = np.zeros((jb.shape[0], 1))
            zl = np.zeros((jl.shape[0], 1))
            if phase2:
                one = np.ones((jo.shape[0], 1))
                return np.vstack([np.hstack([-jb, zb]), np.hstack([jb, zb]), np.hstack([jl, zl]),
                                  np.hstack([-jo, one]), np.hstack([jo, one])])
            one = np.ones((jb.shape[0], 1))
            return np.vstack([np.hstack([-jb, one]), np.hstack([jb, one]), np.hstack([jl, zl])])

        if phase2:
            lo0, _ = self._lj(self.fo, g, xz, xp)
            t0 = float(np.max(np.abs(lo0 - self.eo)))
        else:
            lb0, _ = self._lj(self.fb, g, xz, xp)
            t0 = float(np.max(np.abs(lb0 - self.eb)))
        v0 = np.concatenate([[g], xz, xp, [t0]])
        bounds = [(None, None)] + [(self.xmin, self.xmax)] * (nz + npol) + [(0.0, None)]
        res = scipy.optimize.minimize(
            obj, v0, jac=True, method="SLSQP", bounds=bounds,
            constraints=[{"type": "ineq", "fun": cons, "jac": cons_jac}],
            options={"maxiter": maxiter, "ftol": 1e-9},
        )
        v = res.x if np.all(np.isfinite(res.x)) else v0
        return split(v)


def _finish(g, xz, xp, xb_all, eb_all, xl, yl):
    """Raise the gain so that the bound holds on every line; return the fit figures."""
    fl = 10.0 ** xl
    zl, pl = 10.0 ** np.asarray(xz), 10.0 ** np.asarray(xp)
    margin = weight_db(fl, g, zl, pl) - yl
    raise_db = 0.0
    if np.min(margin) < 0.0:
        raise_db = float(-np.min(margin)) + 1e-9 * max(1.0, abs(g))
        g = g + raise_db
        margin = margin + raise_db
    dev = float(np.max(np.abs(weight_db(10.0 ** xb_all, g, zl, pl) - eb_all)))
    return g, raise_db, dev, float(np.min(margin))


def _cascade_ss(k_dc: float, wz: np.ndarray, wp: np.ndarray):
    """State-space W as a cascade of first-order sections (1 + s/wz)/(1 + s/wp) and 1/(1 + s/wp):
    a triangular A matrix whose eigenvalues are exactly -wp, well conditioned even when corners
    coincide (a polynomial transfer function is not)."""
    import control

    wz, wp = np.sort(wz), np.sort(wp)
    sections = []
    for i, p_ in enumerate(wp):
        num = [1.0 / wz[i], 1.0] if i < wz.size else [1.0]
        sections.append(control.ss(control.tf(num, [1.0 / p_, 1.0])))
    sys = sections[0] * k_dc
    for sec in sections[1:]:
        sys = control.series(sys, sec)
    return sys


def fit_weight(
    freqs_hz,
    envelope_mag,
    etfe_mag,
    tol_db: float = 3.0,
    max_order: int = 10,
    *,
    f_rolloff_hz: float | None = None,
    polish_out_of_band: bool = True,
) -> WeightFit:
    r"""Fit a stable, minimum-phase, strictly proper uncertainty weight :math:`W(s)` (paper Fig. 7).

    .. math:: W(s) = K\,\frac{\prod_{i=1}^{n_z}(1 + s/\omega_{z,i})}{\prod_{j=1}^{n_p}(1 + s/\omega_{p,j})},
              \qquad \omega_{z,i}, \omega_{p,j} > 0,\quad n_p \ge n_z + 1,

    so every pole and zero is real and in the open left half-plane (stable, minimum phase) and
    :math:`W` is strictly proper. Method (section 5, after the first-order asymptotic Bode
    approximations the paper cites):

    1. *Asymptotes*: starting from a constant at the low-frequency level of the envelope, walk up
       in frequency and add a zero where the envelope rises ``delta`` dB above the straight-line
       asymptote, a pole where it falls ``delta`` below, each corner placed where the new
       asymptote meets the envelope (``delta = tol_db`` first). The target is the envelope over
       the band and its extension (:class:`Envelope`) from a decade below the band to a decade
       past ``f_rolloff_hz``, whose final 20 dB/decade fall yields the extra pole for strict
       properness (poles are added at ``f_rolloff_hz`` until :math:`n_p \ge n_z + 1`).
    2. *Moving the corners*: the gain and the corner frequencies are refined (SLSQP on
       log-frequencies, analytic gradients) to minimise the largest deviation in dB from the
       envelope on the measured band, subject to :math:`|W| \ge` ETFE on the lines, with a
       light least-squares pull towards the extension outside the band.
    3. *Order*: if the deviation exceeds ``tol_db``, steps 1-2 are repeated with ``delta``
       halved (more corners; candidates up to ``max_order + 6`` poles are pruned back to
       ``max_order`` by removing the pole-zero pair that hurts least and re-optimising), then
       corner pairs are added where the deviation is largest, up to ``max_order`` poles. Once
       within ``tol_db``, pole-zero pairs are removed while the fit stays within ``tol_db``
       (lowest order). If nothing reaches ``tol_db`` the smallest deviation is returned with
       ``within_tol=False``.
    4. *Out of band* (``polish_out_of_band``): with the in-band deviation allowed to grow a third
       of the way from what step 3 reached to ``tol_db``, the largest deviation from the
       extension outside the band is minimised (the paper's weight is "strictly proper ... where
       it does not violate the 3 dB band inside the measured range"; this keeps |W| sane on the
       wide grid of the mu analysis). Out of band |W| follows the extension only as closely as a
       low-order real-pole weight can.
    5. *Hard constraint of eq. (6)*: after every optimisation the gain is raised, if needed,
       until :math:`|W(j2\pi f_i)| \ge` ``etfe_mag[i]`` on every line; the raise is reported in
       ``gain_raise_db`` and included in ``max_dev_db``.

    Parameters
    ----------
    freqs_hz : array_like
        Strictly increasing line frequencies (Hz) of the ETFE.
    envelope_mag : Envelope or array_like
        The envelope (:func:`peak_envelope`), or its magnitudes at ``freqs_hz`` (then
        interpolated in log-log and extended as in :class:`Envelope`).
    etfe_mag : array_like
        ETFE magnitudes :math:`|Y/X - \bar Y/\bar X|` at ``freqs_hz`` (finite, >= 0).
    tol_db : float
        Allowed deviation from the envelope on the band (the paper's 3 dB).
    max_order : int
        Largest number of poles.
    f_rolloff_hz : float, optional
        Only with an array envelope: start of its high-frequency roll-off (default 10 f_hi).
    polish_out_of_band : bool
        Run step 4.

    Returns
    -------
    WeightFit
        ``within_tol`` tells whether ``max_dev_db <= tol_db``; ``bound_holds`` whether eq. (6)
        holds on every line.

    Raises
    ------
    ValueError
        Empty or non-finite ETFE, negative magnitudes, non-increasing frequencies, mismatched
        lengths, or bad ``tol_db`` / ``max_order``.
    """
    import control

    f, m = _check_freq_mag(freqs_hz, etfe_mag, "etfe_mag")
    tol_db = float(tol_db)
    if not (tol_db > 0 and math.isfinite(tol_db)):
        raise ValueError(f"tol_db must be > 0, got {tol_db!r}")
    if int(max_order) != max_order or max_order < 1:
        raise ValueError(f"max_order must be an integer >= 1, got {max_order!r}")
    max_order = int(max_order)
    if isinstance(envelope_mag, Envelope):
        env = envelope_mag
        if f_rolloff_hz is not None:
            raise ValueError("f_rolloff_hz is taken from the Envelope; do not pass it as well")
    else:
        env = Envelope.from_samples(f, envelope_mag, f_rolloff_hz=f_rolloff_hz)
    f_lo, f_hi = float(f[0]), float(f[-1])
    x_lo, x_hi = math.log10(f_lo), math.log10(f_hi)
    x_roll = math.log10(env.f_rolloff_hz)
    yl = _to_db(m)
    xl = np.log10(f)

    # grids: band for the final check (dense + lines), band for the optimiser (coarser: the
    # envelope and |W| are smooth on a 0.02-decade scale), extension (below and above the band)
    n_band = max(50, int(math.ceil((x_hi - x_lo) * 200)))
    xb_all = np.unique(np.concatenate([np.linspace(x_lo, x_hi, n_band), xl]))
    eb_all = env.db(10.0 ** xb_all)
    xb_opt = np.linspace(x_lo, x_hi, max(20, int(math.ceil((x_hi - x_lo) * 30))))
    eb_opt = env.db(10.0 ** xb_opt)
    xo = np.concatenate([np.linspace(x_lo - 1.0, x_lo, 60, endpoint=False),
                         np.linspace(x_hi, x_roll + 1.0, max(60, int((x_roll + 1 - x_hi) * 60)))[1:]])
    eo = env.db(10.0 ** xo)
    x_track = np.arange(x_lo - 1.0, x_roll + 1.0 + 1e-12, 0.005)
    e_track = env.db(10.0 ** x_track)
    xmin, xmax = x_lo - 2.0, x_roll + 2.0
    # only lines that come within tol of the envelope can be violated while |W - E| <= tol;
    # the others are checked after each solve (and the gain raised if one is not bounded)
    near = (env.db(f) - yl) <= 1.2 * tol_db
    prob = _Problem(xb_opt, eb_opt, xo, eo, xl[near], yl[near], tol_db, 0.02, xmin, xmax)

    history: list[dict] = []
    cap = max_order + 6  # intermediate candidates may be richer; they are pruned to max_order

    def refine_and_record(g, xz, xp, how):
        xz, xp = np.sort(np.asarray(xz, float)), np.sort(np.asarray(xp, float))
        while xp.size < xz.size + 1:
            xp = np.append(xp, x_roll)
        if xp.size > cap:
            return None
        g, xz, xp = prob.solve(g, xz, xp)
        g2, raise_db, dev, margin = _finish(g, xz, xp, xb_all, eb_all, xl, yl)
        cand = (int(xp.size), dev, g2, np.sort(xz), np.sort(xp), raise_db, margin)
        history.append({"how": how, "order": int(xp.size), "n_zeros": int(xz.size),
                        "max_dev_db": dev, "gain_raise_db": raise_db})
        return cand

    def ok(c):
        return c is not None and c[1] <= tol_db and c[0] <= max_order

    def removals(c):
        """Cheapest removals first: drop a zero with its nearest pole (or a surplus pole), keep
        the rest, re-centre the gain, rank by the resulting deviation (no re-optimisation)."""
        _, _, g, xz, xp, _, _ = c
        opts = []
        pairs = set()
        for i in range(xz.size):
            j = int(np.argmin(np.abs(xp - xz[i])))
            pairs.add((i, j))
        if xp.size > xz.size + 1:
            pairs |= {(None, j) for j in range(xp.size)}
        for i, j in pairs:
            z2 = xz if i is None else np.delete(xz, i)
            p2 = np.delete(xp, j)
            d = weight_db(10.0 ** xb_opt, g, 10.0 ** z2, 10.0 ** p2) - eb_opt
            g2 = g - 0.5 * (d.max() + d.min())
            opts.append((0.5 * (d.max() - d.min()), g2, z2, p2))
        opts.sort(key=lambda o: o[0])
        return opts

    def prune(c, force_to: int | None):
        """Remove corners a pair at a time (three cheapest removals tried, re-optimised): forced
        while the order exceeds `force_to`, then further while the fit stays within tol_db."""
        while c[3].size >= 1 or c[4].size > c[3].size + 1:
            forced = force_to is not None and c[0] > force_to
            t_best = None
            for _, g2, z2, p2 in removals(c)[:3]:
                t = refine_and_record(g2, z2, p2, "pruned")
                if t is not None and (t_best is None or t[1] < t_best[1]):
                    t_best = t
                if t_best is not None and t_best[1] <= tol_db:
                    break  # good enough: do not try the other removals
            if t_best is None:
                break
            if forced or t_best[1] <= tol_db:
                c = t_best
            else:
                break
        return c

    candidates: list[tuple] = []
    best = None
    delta = tol_db
    # W >= data on the lines, so no weight beats max(data - envelope): if that exceeds tol_db
    # (an envelope passed in below the ETFE), one candidate is enough
    hopeless = float(np.max(yl - env.db(f))) > tol_db
    for _ in range(1 if hopeless else 4):
        g0, z0, p0 = _asymptotic_corners(x_track, e_track, delta)
        c = refine_and_record(g0, z0, p0, f"asymptotes delta={delta:.3g} dB")
        delta /= 2.0
        if c is None:
            break
        candidates.append(c)
        if c[1] <= tol_db:
            c = prune(c, max_order)
            candidates.append(c)
            if ok(c):
                best = c
                break
    if best is None and not hopeless:
        # greedy: from the best admissible candidate, add a zero/pole pair around the worst
        # in-band deviation, re-optimise, repeat up to max_order
        admissible = [c for c in candidates if c[0] <= max_order]
        if not admissible:
            c = refine_and_record(float(np.max(eb_all)), np.array([]), np.array([x_roll]), "constant")
            admissible = [c]
            candidates.append(c)
        cur = min(admissible, key=lambda c: c[1])
        for _ in range(max_order):
            if cur[0] + 1 > max_order:
                break
            _, _, g, xz, xp, _, _ = cur
            d = weight_db(10.0 ** xb_all, g, 10.0 ** xz, 10.0 ** xp) - eb_all
            k = int(np.argmax(np.abs(d)))
            xs = xb_all[k]
            if d[k] < 0:  # too low: a local rise, zero then pole
                xz2, xp2 = np.append(xz, xs - 0.15), np.append(xp, xs + 0.15)
            else:
                xz2, xp2 = np.append(xz, xs + 0.15), np.append(xp, xs - 0.15)
            c = refine_and_record(g, xz2, xp2, "added corner pair")
            if c is None:
                break
            candidates.append(c)
            cur = c  # keep growing from the last candidate (the best is kept in `candidates`)
            if ok(c):
                best = prune(c, None)
                break
    if best is None:
        admissible = [c for c in candidates if c[0] <= max_order]
        if not admissible:
            c = refine_and_record(float(np.max(eb_all)), np.array([]), np.array([x_roll]), "constant")
            admissible = [c]
        best = min(admissible, key=lambda c: c[1])
    elif polish_out_of_band:
        # phase 2: with the in-band deviation held below a third of the way from what phase 1
        # reached to tol_db, bring |W| as close as possible to the extension out of band
        _, dev1, g, xz, xp, _, _ = best
        limit = dev1 + (tol_db - dev1) / 3.0
        g2, z2, p2 = prob.solve(g, xz, xp, band_limit=limit)
        g2, raise_db, dev, margin = _finish(g2, z2, p2, xb_all, eb_all, xl, yl)
        history.append({"how": "out-of-band polish", "order": int(p2.size), "n_zeros": int(z2.size),
                        "max_dev_db": dev, "gain_raise_db": raise_db})
        if dev <= tol_db:
            best = (int(p2.size), dev, g2, np.sort(z2), np.sort(p2), raise_db, margin)
    order, dev, g, xz, xp, raise_db, margin = best
    zeros_hz, poles_hz = 10.0 ** xz, 10.0 ** xp
    k_dc = 10.0 ** (g / _DB)
    wz, wp = 2.0 * np.pi * zeros_hz, 2.0 * np.pi * poles_hz
    W = control.zpk(-wz, -wp, k_dc * np.prod(wp) / np.prod(wz) if wz.size else k_dc * np.prod(wp))
    return WeightFit(
        W=W, W_ss=_cascade_ss(k_dc, wz, wp), gain=k_dc, zeros_hz=zeros_hz, poles_hz=poles_hz, order=int(order),
        max_dev_db=float(dev), within_tol=bool(dev <= tol_db), bound_holds=bool(margin >= 0.0),
        min_margin_db=float(margin), gain_raise_db=float(raise_db), tol_db=tol_db,
        band_hz=(f_lo, f_hi), envelope=env, history=history,
    )


# =============================================================================================
# 5. plot
# =============================================================================================
def plot_weight(
    ax,
    fit: WeightFit,
    etfe_freqs_hz=None,
    etfe_mag=None,
    *,
    unit: str = "m/A",
    f_plot_hz: tuple[float, float] | None = None,
    title: str | None = None,
):
    """Fig. 7 equivalent on a matplotlib axis: ETFE points, envelope, fitted |W| and the
    +/- ``tol_db`` band around the envelope, log frequency axis in Hz, magnitude in dB re 1
    ``unit`` (the unit of the mismatch). ``etfe_*`` default to the data stored in the envelope.
    Returns ``ax``."""
    env = fit.envelope
    fe = env.freqs_hz if etfe_freqs_hz is None else np.asarray(etfe_freqs_hz, float)
    me = env.mag if etfe_mag is None else np.asarray(etfe_mag, float)
    f_lo, f_hi = fit.band_hz
    lo, hi = f_plot_hz if f_plot_hz is not None else (f_lo / 10.0, max(env.f_rolloff_hz, f_hi) * 10.0)
    fp = np.logspace(math.log10(lo), math.log10(hi), 600)
    fb = np.logspace(math.log10(f_lo), math.log10(f_hi), 300) if f_hi > f_lo else np.array([f_lo])
    eb = env.db(fb)
    ax.fill_between(fb, eb - fit.tol_db, eb + fit.tol_db, color="0.85", label=f"envelope ±{fit.tol_db:g} dB")
    ax.semilogx(fp, env.db(fp), "k--", lw=1.0, label="peak envelope (extended)")
    ax.semilogx(fp, fit.db(fp), "C0-", lw=1.8,
                label=f"|W| (order {fit.order}, max dev {fit.max_dev_db:.2f} dB)")
    ax.semilogx(fe, _DB * np.log10(np.maximum(me, np.max(me) * 1e-12)), "C3o", ms=4,
                label="ETFE |Y/X − Ȳ/X̄| (eq. 6)")
    ax.set_xscale("log")
    ax.set_xlabel("Frequency (Hz)")
    ax.set_ylabel(f"Magnitude (dB re 1 {unit})")
    if title:
        ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return ax
