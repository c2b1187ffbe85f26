r"""Reproducible features of a record: what a replay can be compared with, and how precisely.

A rig and its replay are two realisations of a noisy loop: converter noise, and a self-sensing
estimate whose error is a pseudo-random function of the loop's state (a replay of the rig's own
model with the rotor mass changed by 1e-12 differs by half the rms of ``u_y``:
``bench/replay_sensitivity.py``). Sample by sample the two never agree; what agrees is what the
excitation determines. A segment of a record is therefore reduced to **features** whose noise
is estimated from the data themselves, for measured and modelled channels alike:

* ``dc``: the sum of each view over the segment, :math:`X_v(0) = \sum_m x_v(m)`;
* ``bins``: the response at the excited frequencies. A periodic excitation recorded over
  :math:`P` whole periods (rectangular window) puts every deterministic response on the grid
  :math:`k = iP`; the features are the DFT values :math:`X_v(k)` at the excited grid bins.
  Another excitation gives Welch cross-spectra with each excited axis' signal :math:`s_a`,
  :math:`F_{v,a}(k) = \frac1K\sum_{seg} X_{v,seg}(k)\,\overline{S_{a,seg}(k)}` at the bins where
  the excitation has power;
* ``lines``: phasors at frequencies the excitation does not explain (a rotating unbalance, say),
  in DFT units (:math:`\tfrac n2 A` for a sinusoid :math:`\mathrm{Re}\,A e^{j\omega t}`), so
  that all frequency features share one scale;
* ``win`` (non-periodic frames): slow trends. The segment is cut into :math:`W` consecutive
  windows of :math:`L` samples, and the window means :math:`\bar x_w` are expanded in the
  orthonormal cosine basis (DCT-II), :math:`c_j = \sum_w \bar x_w \sqrt{2/W}\cos(\pi j (w +
  \tfrac12)/W)`, :math:`j = 1 \dots W-1` (the constant, :math:`j = 0`, is the ``dc`` feature): a
  response to a slowly varying reference, a drift. Noise that is white across windows keeps its
  variance in every coefficient and the coefficients independent;
* ``band`` (the device's band views, :attr:`ssamb.device.FeatureSpec.band_views`): the loop's
  response to its own noise, where no excitation is usable. In bands of Welch bins without
  excitation power, :math:`b = \ln \hat P - (\psi(\nu/2) - \ln(\nu/2))`: the log of the
  band's power spectral density, less the bias of the log of a :math:`\chi^2_\nu/\nu` variable
  (:math:`\nu` its degrees of freedom, :func:`band_dof`), so that the difference of two
  estimates with different :math:`\nu` (the data; the mean over replays of their densities) is
  unbiased. Its variance is :math:`\psi'(\nu/2)` (trigamma), and the estimates of two views
  in one band correlate as their coherence.

**Noise.** Each feature comes with the complex covariance across views of its noise,
:math:`C(k) = E[\,\delta X(k)\,\delta X(k)^H]`. For a periodic frame it is the band average of
:math:`X(k)X(k)^H` over the off-grid bins (which hold only what is not synchronous with the
excitation: noise, the self-sensing estimator's pseudo-noise and unrelated lines, whose few
bins a band average barely notices), rescaled per view by the pooled period-to-period spread at
the excited bins when there are enough periods (the estimator's pseudo-noise is cyclostationary:
the off-grid floor can be 10-20 % low at the lines). The DC covariance is that of the lowest
off-grid bins. For a Welch frame the covariance of the residual of a per-bin regression on the
excitation across segments (Bendat & Piersol) gives the noise of the cross-spectra; the same
regression at the lowest Welch bins gives the low-frequency noise of ``dc`` and ``win`` (a
window mean of :math:`L` samples has variance :math:`f_s S(0^+)/(2L)`, :math:`S` the one-sided
density), without the response the excitation drives there.

The covariance of a **difference** between a measured and a modelled feature is the sum of the
two covariances (independent noise): :class:`Whitener` factors it once and turns any such
difference into a real vector with unit covariance, the currency of every fit and test.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import fft as sfft
from scipy import signal

from .spectra import Frame, _bands

__all__ = ["Features", "Layout", "make_layout", "features", "low_frequency_from", "Whitener", "line_phasors",
           "scale_views", "replicate_factors", "band_plan", "band_dof", "log_bias", "log_var"]


@dataclass(frozen=True)
class Layout:
    """What features a segment yields.

    Attributes
    ----------
    frame : Frame
        The segment (periodic or not; :func:`ssamb.closeloop.spectra.make_frame`).
    bins : numpy.ndarray
        Periodic frames: the excited grid bins (of the whole frame's DFT). Welch frames: the
        bins (of one Welch segment) where the excitation has power.
    axes : tuple
        Welch frames: the excited axes whose signals the cross-spectra use (one feature block
        per axis); periodic frames: ``()``.
    nperseg : int
        Welch segment length (0 for periodic frames).
    lines_hz : tuple
        Frequencies of the line features.
    views : tuple
        The views compared (the device's cost views).
    signals : dict
        Welch frames: per axis, the excitation over the whole record.
    device : ssamb.device.Device or None
        The device whose views these are (to derive them from channels).
    win_len, n_win : int
        Non-periodic frames: samples per window and windows of the ``win`` features (0: none).
    band_views : tuple
        Views whose ``band`` features are compared (a subset of ``views``).
    bands : tuple of numpy.ndarray
        The Welch bins (segments of ``band_nper`` samples) of each band.
    band_floor : tuple
        Per band view, the smallest one-sided density assumed (the view's noise floor as white
        noise): a channel without noise would otherwise give the log of zero.
    dl_views, dl_hz, dl_floor : tuple
        Views compared at the device's own lines only (``dl`` features,
        :attr:`ssamb.device.FeatureSpec.device_line_views`), those lines, and the views' noise
        floors per sample.
    """

    frame: Frame
    bins: np.ndarray
    axes: tuple
    nperseg: int
    lines_hz: tuple
    views: tuple = ()
    signals: dict = field(default_factory=dict, repr=False)
    device: object = field(default=None, repr=False, compare=False)
    win_len: int = 0
    n_win: int = 0
    band_views: tuple = ()
    bands: tuple = field(default=(), repr=False)
    band_nper: int = 0
    band_floor: tuple = ()
    dl_views: tuple = ()
    dl_hz: tuple = ()
    dl_floor: tuple = ()
    #: the excitations' Welch segments, per (axis, segment, length): the same for every replay
    _segments: dict = field(default_factory=dict, repr=False, compare=False)

    def excitation_segments(self, axis: str, seg: slice, nper: int) -> np.ndarray:
        """:func:`_welch_segments` of the excitation of ``axis`` over ``seg`` (segments x bins),
        computed once per layout: every replay compared over it has the same excitation."""
        key = (axis, seg.start, seg.stop, nper)
        if key not in self._segments:
            self._segments[key] = _welch_segments(self.signals[axis][seg][None, :], nper)[:, 0, :]
        return self._segments[key]

    @property
    def f_bins_hz(self) -> np.ndarray:
        fs = self.frame.fs_hz
        return self.bins * fs / (self.frame.n if self.nperseg == 0 else self.nperseg)

    @property
    def f_bands_hz(self) -> np.ndarray:
        """Centre frequency of each band (mean of its bins' frequencies)."""
        return np.array([float(np.mean(b)) * self.frame.fs_hz / self.band_nper for b in self.bands])

    @property
    def all_views(self) -> tuple:
        """Every view with entries in the whitened vector: the compared views, then those compared
        at the device's lines only."""
        return tuple(self.views) + tuple(self.dl_views)

    @property
    def t_win_s(self) -> np.ndarray:
        """Centre time of each window (from the record's start)."""
        fr = self.frame
        return (fr.i0 + (np.arange(self.n_win) + 0.5) * self.win_len) / fr.fs_hz

    def with_lines(self, lines_hz) -> "Layout":
        """The same layout with other line frequencies."""
        import dataclasses

        return dataclasses.replace(self, lines_hz=tuple(float(f) for f in lines_hz))


def make_layout(frame: Frame, signals: dict, lines_hz=(), views=(), max_bins: int = 64, device=None,
                band_views=None, floor=None, exclude_hz=(), dl_views=(), dl_floor=None) -> Layout:
    """The feature layout of ``frame``.

    Parameters
    ----------
    signals : dict
        Per excited axis, the excitation over the whole record (the reference, or the current
        injection when the reference is constant).
    lines_hz : sequence of float
        Line frequencies to read as features.
    views : sequence of str
        The views compared.
    max_bins : int
        Welch frames: at most this many bins, the strongest of the excitation's power.
    device : ssamb.device.Device, optional
        The device (its :attr:`~ssamb.device.FeatureSpec.band_views` are the default band views).
    band_views : sequence of str, optional
        Views whose power spectra are compared in bands (default: the device's, among ``views``).
    floor : sequence of float, optional
        Per view of ``views``, the smallest noise level per sample (the bands' floor).
    exclude_hz : sequence of float
        Frequencies the bands leave out (the device's own lines).
    dl_views, dl_floor : sequences
        Views compared at the device's own lines (``exclude_hz``) only, and their noise floors
        per sample.
    """
    if band_views is None:
        band_views = tuple(getattr(getattr(device, "features", None), "band_views", ()) or ())
    band_views = tuple(v for v in views if v in band_views)
    fl = dict(zip(views, np.zeros(len(views)) if floor is None else np.asarray(floor, float)))
    extra = {}
    dl_hz = tuple(float(f) for f in exclude_hz if 0 < f < frame.fs_hz / 2 - frame.df_hz)
    if dl_views and dl_hz:
        extra.update(dl_views=tuple(dl_views), dl_hz=dl_hz,
                     dl_floor=tuple(np.zeros(len(dl_views)) if dl_floor is None else np.asarray(dl_floor, float)))
    if band_views:
        bnper = _welch_length(frame.n)
        bands = band_plan(frame, signals, bnper, exclude_hz)
        if bands:
            extra.update(band_views=band_views, bands=tuple(bands), band_nper=bnper,
                         band_floor=tuple(2.0 * fl[v] ** 2 / frame.fs_hz for v in band_views))
    if frame.periodic:
        kb = np.unique(np.concatenate([np.asarray(v, int) for v in frame.excited.values()])) if frame.excited else \
            np.zeros(0, int)
        return Layout(frame, kb, (), 0, tuple(float(f) for f in lines_hz), tuple(views), device=device, **extra)
    nper = _welch_length(frame.n)
    seg = slice(frame.i0, frame.i0 + frame.n)
    power = np.zeros(nper // 2 + 1)
    for s in signals.values():
        _, p = signal.welch(s[seg], nperseg=nper, noverlap=nper // 2, window="hann", detrend="constant")
        power = np.maximum(power, p / max(p.max(), 1e-300))
    cand = np.flatnonzero(power > 1e-3)
    cand = cand[cand >= 1]
    if len(cand) > max_bins:
        cand = np.sort(cand[np.argsort(-power[cand])[:max_bins]])
    L = max(nper // 2, 1)
    W = frame.n // L
    if W >= 3:
        extra.update(win_len=frame.n // W, n_win=W)
    return Layout(frame, cand, tuple(signals), nper, tuple(float(f) for f in lines_hz), tuple(views),
                  {a: np.asarray(s, float) for a, s in signals.items()}, device, **extra)


def band_plan(frame: Frame, signals: dict, nper: int, exclude_hz=(), n_bands: int = 16,
              min_bins: int = 4) -> list:
    """Bands of Welch bins (segments of ``nper`` samples over ``frame``) without excitation power.

    A bin is usable when every excitation's Welch power there is below 1e-4 of its largest
    (all bins when nothing is excited), it is not one of the two lowest (the segments' mean
    removal) and it lies more than two bins from each of ``exclude_hz``. Usable bins are grouped
    into about ``n_bands`` log-spaced bands of at least ``min_bins`` bins each.

    Returns
    -------
    list of numpy.ndarray
        The bins of each band, lowest band first (empty when fewer than ``min_bins`` are usable).
    """
    nb = nper // 2 + 1
    if frame.n < nper:
        return []
    seg = slice(frame.i0, frame.i0 + frame.n)
    usable = np.ones(nb, bool)
    usable[:2] = False
    for s in signals.values():
        x = np.asarray(s, float)[seg]
        if np.ptp(x) == 0:
            continue
        _, p = signal.welch(x, nperseg=nper, noverlap=nper // 2, window="hann", detrend="constant")
        usable &= p <= 1e-4 * max(float(p.max()), 1e-300)
    df = frame.fs_hz / nper
    k = np.arange(nb)
    for f in np.atleast_1d(np.asarray(exclude_hz, float)):
        usable &= np.abs(k * df - f) > 2.5 * df
    idx = np.flatnonzero(usable)
    if len(idx) < min_bins:
        return []
    edges = np.geomspace(2, nb, n_bands + 1)
    out, cur = [], []
    j = 0
    for e in edges[1:]:
        while j < len(idx) and idx[j] < e:
            cur.append(idx[j])
            j += 1
        if len(cur) >= min_bins:
            out.append(np.asarray(cur, int))
            cur = []
    if cur:
        if out:
            out[-1] = np.concatenate([out[-1], np.asarray(cur, int)])
        elif len(cur) >= min_bins:
            out.append(np.asarray(cur, int))
    return out


def band_dof(bins: np.ndarray, n_seg: int) -> float:
    r"""Degrees of freedom :math:`\nu` of the mean Welch density over the set ``bins`` (Hann,
    half-overlapping segments, ``n_seg`` of them).

    Each bin's averaged periodogram has :math:`\nu = 2 K`, :math:`K = n_{seg}/1.06`; the
    periodograms of Hann bins one and two apart correlate with :math:`(2/3)^2` and
    :math:`(1/6)^2`, so a sum over :math:`b` bins with :math:`n_1, n_2` such pairs has
    :math:`\nu = 2 K b^2 / (b + \tfrac89 n_1 + \tfrac1{18} n_2)` (Satterthwaite).
    """
    b = np.ascontiguousarray(bins, dtype=np.int64)
    nb, n1, n2 = _neighbour_pairs(b.tobytes())
    k_eff = max(1.0, n_seg / 1.06)
    return float(2.0 * k_eff * nb ** 2 / (nb + 8.0 / 9.0 * n1 + n2 / 18.0))


@functools.lru_cache(maxsize=1024)
def _neighbour_pairs(raw: bytes) -> tuple[int, int, int]:
    """Bins of a band (int64 bytes), and its pairs of bins one and two apart (every replay's
    features read the same bands)."""
    b = np.frombuffer(raw, dtype=np.int64)
    d = np.abs(b[:, None] - b[None, :])
    return len(b), int(np.sum(d == 1)) // 2, int(np.sum(d == 2)) // 2


def log_bias(nu: float) -> float:
    r""":math:`E \ln(\chi^2_\nu/\nu) = \psi(\nu/2) - \ln(\nu/2)`."""
    from scipy.special import digamma

    return float(digamma(nu / 2.0) - math.log(nu / 2.0))


def log_var(nu: float) -> float:
    r""":math:`\mathrm{var}\,\ln\chi^2_\nu = \psi'(\nu/2)`."""
    from scipy.special import polygamma

    return float(polygamma(1, nu / 2.0))


def _band_spectra(layout: Layout, xs: list) -> tuple[np.ndarray, np.ndarray, int]:
    """The band views' summed cross-spectra per band, averaged over segments and over the signal
    sets ``xs`` (each V x n over the frame): ``(C (B, Vb, Vb) complex, one-sided density scale,
    segments)``."""
    idx = [layout.views.index(v) for v in layout.band_views]
    acc = None
    n_seg = 0
    for x in xs:
        Y = _welch_segments(x[idx], layout.band_nper)                   # S x Vb x bins
        n_seg = Y.shape[0]
        C = np.stack([np.einsum("svk,suk->vu", Y[:, :, b], Y[:, :, b].conj()) / Y.shape[0] for b in layout.bands])
        acc = C if acc is None else acc + C
    w2 = float(np.sum(signal.windows.hann(layout.band_nper, sym=False) ** 2))
    return acc / len(xs), 2.0 / (layout.frame.fs_hz * w2), n_seg


def _band_values(layout: Layout, xs: list, noise: bool):
    """``band`` values (B, Vb) of the mean density of the signal sets ``xs`` (module docstring), and
    with ``noise`` their covariance (B, Vb, Vb): trigamma times the band's coherence."""
    C, scale, n_seg = _band_spectra(layout, xs)
    sizes = [len(b) for b in layout.bands]
    floor = np.asarray(layout.band_floor, float)
    P = np.real(np.einsum("bvv->bv", C)) * scale / np.asarray(sizes)[:, None] + floor[None, :]
    nus = [band_dof(b, n_seg) * len(xs) for b in layout.bands]
    vals = np.log(P) - np.array([log_bias(nu) for nu in nus])[:, None]
    if not noise:
        return vals, None
    cov = np.zeros(C.shape)
    for j, nu in enumerate(nus):
        d = np.sqrt(np.maximum(np.real(np.diag(C[j])), 1e-300))
        coh = np.abs(C[j] / np.outer(d, d)) ** 2
        # the floor is noise of its own in every view: it lowers the coherence
        pv = np.real(np.diag(C[j])) * scale / sizes[j]
        share = pv / (pv + floor)
        coh = coh * np.sqrt(np.outer(share, share))
        np.fill_diagonal(coh, 1.0)
        cov[j] = log_var(nu) * coh
    return vals, cov


def _window_means(layout: Layout, x: np.ndarray) -> np.ndarray:
    """Means of the ``n_win`` consecutive windows of ``win_len`` samples: V x W."""
    W, L = layout.n_win, layout.win_len
    return x[:, : W * L].reshape(x.shape[0], W, L).mean(axis=2)


def _win_values(layout: Layout, x: np.ndarray) -> np.ndarray:
    """``win`` values: the window means' orthonormal cosine coefficients 1..W-1, (W-1) x V."""
    if not layout.n_win:
        return np.zeros((0, x.shape[0]))
    return sfft.dct(_window_means(layout, x), type=2, norm="ortho", axis=1)[:, 1:].T


def _welch_length(n: int) -> int:
    """Welch segment length: a power of two, 16 half-overlapping segments or more, 256-16384; a
    record shorter than 512 samples gets segments of at most half its length (16 at least)."""
    nper = int(2 ** max(8, min(14, int(math.log2(max(n // 8, 256))))))
    return nper if nper <= n // 2 else int(2 ** max(4, int(math.log2(max(n // 2, 16)))))


@dataclass
class Features:
    """Features of one signal set (measured or modelled) over a layout.

    ``dc`` (V,), ``bins`` (K, V) or (A, K, V) for Welch frames, ``lines`` (L, V) complex, each
    with its noise covariance ``cov_dc`` (V, V), ``cov_bins`` (K, V, V) or (A, K, V, V),
    ``cov_lines`` (L, V, V); ``win`` (W-1, V) and ``band`` (B, Vb) real, with ``cov_win``
    (W-1, V, V) and ``cov_band`` (B, Vb, Vb); ``dl`` (Ld, Vd) complex at the device's lines with
    ``cov_dl`` (Ld, Vd, Vd). ``factors`` are the per-view ``(bins, dc)``
    factors applied to the off-grid covariances (:func:`_period_factors`), to reuse on another
    segment of the record (``(bins, dc, win, band)`` after :func:`scale_views`).
    """

    dc: np.ndarray
    bins: np.ndarray
    lines: np.ndarray
    cov_dc: np.ndarray
    cov_bins: np.ndarray
    cov_lines: np.ndarray
    factors: tuple = ()
    win: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    cov_win: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    band: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    cov_band: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    dl: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), complex))
    cov_dl: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0), complex))


def _stack(layout: Layout, ch: dict, seg: slice) -> np.ndarray:
    return np.stack([np.asarray(ch[v], float)[seg] for v in layout.views])


def _band_cov(Y: np.ndarray, usable: np.ndarray, n_bands: int = 32, min_bins: int = 24,
              outlier: float = 15.0) -> np.ndarray:
    r"""Per bin, the band average of ``Y[:, k] Y[:, k]^H`` over the usable bins of its band.

    A bin whose power in any row exceeds ``outlier`` times that row's median power in the band
    is left out: the average is of noise, and a line the excitation lacks (an unbalance), or its
    leakage, would otherwise raise the floor around itself and hide from its own test (the
    power of a noise bin is exponential: 15 medians are 10.4 means, exceeded with probability
    3e-5).
    """
    nv, nb = Y.shape
    C = np.zeros((nb, nv, nv), complex)
    P = np.abs(Y) ** 2
    for a, b in _bands(usable, n_bands, min_bins):
        sel = np.flatnonzero(usable[a:b]) + a
        if len(sel) < 2:
            sel = np.arange(a, b)
        med = np.median(P[:, sel], axis=1, keepdims=True)
        keep = sel[np.all(P[:, sel] <= outlier * np.maximum(med, 1e-300), axis=0)]
        sel = keep if len(keep) >= max(2, len(sel) // 2) else sel
        Z = Y[:, sel]
        C[a:b] = (Z @ Z.conj().T) / len(sel)
    return C


def _period_factors(layout: Layout, x: np.ndarray, diag_bins: np.ndarray, diag_dc: np.ndarray):
    r"""Per-view factors on the off-grid covariance from the period-to-period spread.

    With :math:`P \ge 6` periods the per-period DFTs :math:`Y_p(l)` at the excited lines give
    :math:`\hat s^2_v = P\,\overline{|Y_p - \bar Y|^2}` (an unbiased estimate of the variance of
    the whole-frame DFT); the factor is the median over lines of :math:`\hat s^2_v/C_{vv}`,
    corrected for the median of a :math:`\chi^2_{2(P-1)}/(2(P-1))` variable, and never below 1
    (the estimator's pseudo-noise is cyclostationary: the off-grid floor can be low at the
    lines). The DC factor compares :math:`P` times the variance of the per-period sums with the
    DC variance (a slow drift shows there), never below 1. Returns ``(bins, dc)`` factors (ones
    with fewer periods).
    """
    fr = layout.frame
    nv = len(layout.views)
    P = fr.n // fr.n_period
    if P < 6 or len(layout.bins) < 5:
        return np.ones(nv), np.ones(nv)
    x = x - _line_components(fr, x, layout.lines_hz)      # a line off the grid spreads over periods
    per = x.reshape(nv, P, fr.n_period)
    Yp = sfft.rfft(per, axis=2)[:, :, layout.bins // P]           # V x P x K
    s2 = P * np.sum(np.abs(Yp - Yp.mean(axis=1, keepdims=True)) ** 2, axis=1) / (P - 1)
    nu = 2 * (P - 1)
    med = (1 - 2 / (9 * nu)) ** 3
    fac = np.maximum(np.median(s2 / np.maximum(diag_bins.T, 1e-300), axis=1) / med, 1.0)
    sums = per.sum(axis=2)
    fac_dc = np.maximum(P * sums.var(axis=1, ddof=1) / np.maximum(diag_dc, 1e-300), 1.0)
    return fac, fac_dc


def scale_views(f: "Features", fac_bins: np.ndarray, fac_dc: np.ndarray, fac_win=None, fac_band=None,
                fac_dl=None) -> "Features":
    r"""The features with their noise covariances scaled per view (``C -> D C D``,
    :math:`D = \mathrm{diag}\sqrt{\mathrm{fac}}`; lines take the bins' factors, windows the DC's
    unless given; ``fac_band`` is per band view, ``fac_dl`` per view compared at the device's
    lines)."""
    import dataclasses

    fac_win = fac_dc if fac_win is None else fac_win
    d, e, w = np.sqrt(fac_bins), np.sqrt(fac_dc), np.sqrt(fac_win)
    kw = {}
    if f.cov_band.size and fac_band is not None:
        b = np.sqrt(np.asarray(fac_band, float))
        kw["cov_band"] = f.cov_band * b[:, None] * b[None, :]
    if f.cov_dl.size and fac_dl is not None:
        b = np.sqrt(np.asarray(fac_dl, float))
        kw["cov_dl"] = f.cov_dl * b[:, None] * b[None, :]
    more = f.cov_win.size or f.cov_band.size or f.cov_dl.size or fac_band is not None or fac_dl is not None
    factors = (np.asarray(fac_bins), np.asarray(fac_dc)) if not more else \
        (np.asarray(fac_bins), np.asarray(fac_dc), np.asarray(fac_win),
         None if fac_band is None else np.asarray(fac_band), None if fac_dl is None else np.asarray(fac_dl))
    return dataclasses.replace(f, cov_bins=f.cov_bins * d[:, None] * d[None, :],
                               cov_lines=f.cov_lines * d[:, None] * d[None, :], cov_dc=f.cov_dc * np.outer(e, e),
                               cov_win=f.cov_win * w[:, None] * w[None, :] if f.cov_win.size else f.cov_win,
                               factors=factors, **kw)


def replicate_factors(fs: list) -> tuple:
    r"""Per-view factors from replicates: the features of ``m`` replays with distinct seeds.

    Bins: the median over bins of the replicates' variance over the predicted (off-grid)
    variance of one replay, corrected for the median of :math:`\chi^2_{2(m-1)}/(2(m-1))`; DC:
    the replicates' variance over the predicted one. Never below 1: a replay's own noise is at
    least what its off-grid bins show (the self-sensing estimator's pseudo-noise and the
    current loops' drift add to it at the lines and at DC). Windows and bands (real entries)
    likewise, over :math:`\chi^2_{m-1}/(m-1)`; the device's lines (complex) as the bins. Returns
    ``(bins, dc)``, or ``(bins, dc, win, band, dl)`` when the features have windows, bands or
    device-line views.
    """
    m = len(fs)
    nv = fs[0].dc.shape[-1]
    has_more = fs[0].win.size > 0 or fs[0].band.size > 0 or fs[0].dl.size > 0
    if m < 3:
        one = np.ones(nv)
        return (one, one, one, np.ones(fs[0].band.shape[-1]), np.ones(fs[0].dl.shape[-1])) if has_more else (one, one)
    B = np.array([f.bins for f in fs])
    emp = np.sum(np.abs(B - B.mean(axis=0)) ** 2, axis=0) / (m - 1)
    pred = np.mean([np.real(np.einsum("...vv->...v", f.cov_bins)) for f in fs], axis=0)
    nu = 2 * (m - 1)
    med = (1 - 2 / (9 * nu)) ** 3
    ratio = (emp / np.maximum(pred, 1e-300)).reshape(-1, emp.shape[-1])
    fac = np.maximum(np.median(ratio, axis=0) / med, 1.0) if ratio.shape[0] else np.ones(nv)
    D = np.array([f.dc for f in fs])
    pred_dc = np.mean([np.diag(f.cov_dc) for f in fs], axis=0)
    fac_dc = np.maximum(D.var(axis=0, ddof=1) / np.maximum(pred_dc, 1e-300), fac)
    if not has_more:
        return fac, fac_dc
    med1 = (1 - 2 / (9 * (m - 1))) ** 3

    def real_factor(vals, covs, width):
        if vals.shape[1] == 0:
            return np.ones(width)
        e = vals.var(axis=0, ddof=1)
        p = np.mean([np.einsum("kvv->kv", c) for c in covs], axis=0)
        return np.maximum(np.median(e / np.maximum(p, 1e-300), axis=0) / med1, 1.0)
    fac_win = real_factor(np.array([f.win for f in fs]), [f.cov_win for f in fs], nv)
    fac_band = real_factor(np.array([f.band for f in fs]), [f.cov_band for f in fs], fs[0].band.shape[-1])
    nd = fs[0].dl.shape[-1]
    if fs[0].dl.size:
        L = np.array([f.dl for f in fs])
        e = np.sum(np.abs(L - L.mean(axis=0)) ** 2, axis=0) / (m - 1)
        p = np.mean([np.real(np.einsum("kvv->kv", f.cov_dl)) for f in fs], axis=0)
        fac_dl = np.maximum(np.median(e / np.maximum(p, 1e-300), axis=0) / med, 1.0)
    else:
        fac_dl = np.ones(nd)
    return fac, fac_dc, fac_win, fac_band, fac_dl


def _line_components(frame: Frame, x: np.ndarray, lines_hz) -> np.ndarray:
    """The sinusoids of the off-grid lines in the rows of ``x`` (time domain; on-grid lines are
    synchronous with the period and left alone)."""
    out = np.zeros_like(x)
    t = frame.t_s
    for f, A in zip(lines_hz, line_phasors(frame, x, lines_hz)):
        k = f / frame.df_hz
        if frame.periodic and abs(k - round(k)) < 1e-9:
            continue
        w = 2 * np.pi * f * t
        out += (2.0 / frame.n) * (A.real[:, None] * np.cos(w) - A.imag[:, None] * np.sin(w))
    return out


def line_phasors(frame: Frame, x: np.ndarray, lines_hz, X: np.ndarray | None = None) -> np.ndarray:
    r"""Phasors of sinusoids at ``lines_hz`` in the rows of ``x`` (V x n), DFT units.

    On-grid frequencies of a periodic frame are the DFT bins themselves (of ``X``, the rows'
    real FFT, when given); any other frequency is a least-squares fit of
    :math:`a\cos\omega t + b\sin\omega t` (time from the record start) with the part
    synchronous with a periodic excitation removed from data and regressors, returned as
    :math:`\tfrac n2 (a - jb)`. With :math:`P` the projector that removes that part and
    :math:`D` the regressors, :math:`(PD)^+ P x = (PD)^+ x`: one cached :math:`2 \times n`
    pseudo-inverse per frame and frequency serves every replay.
    """
    out = np.zeros((len(lines_hz), x.shape[0]), complex)
    for i, f in enumerate(lines_hz):
        k = f / frame.df_hz
        if frame.periodic and abs(k - round(k)) < 1e-9:
            if X is None:
                X = sfft.rfft(x, axis=1)
            out[i] = X[:, int(round(k))]
            continue
        coef = _offgrid_pinv(frame, float(f)) @ x.T
        out[i] = 0.5 * frame.n * (coef[0] - 1j * coef[1])
    return out


_PINV: dict = {}


def _offgrid_pinv(frame: Frame, f: float) -> np.ndarray:
    r"""Pseudo-inverse of the de-synchronised regressors :math:`(\cos\omega t, \sin\omega t)` of
    one frame (cached: the frame's samples and the frequency are the key)."""
    key = (frame.fs_hz, frame.i0, frame.n, frame.periodic, frame.n_period, f)
    if key not in _PINV:
        if len(_PINV) >= 64:          # 2 x n floats each: about 100 MB at most for 2 s records
            _PINV.clear()
        w = 2 * np.pi * f * frame.t_s
        D = np.column_stack([_desync(frame, np.cos(w)), _desync(frame, np.sin(w))])
        _PINV[key] = np.linalg.pinv(D, rcond=np.finfo(float).eps * frame.n)
    return _PINV[key]


def _desync(frame: Frame, x: np.ndarray) -> np.ndarray:
    """``x`` without its part synchronous with the period (periodic frames), else without its mean."""
    if not frame.periodic:
        return x - np.mean(x)
    r = x.reshape(frame.n // frame.n_period, frame.n_period)
    return (r - r.mean(axis=0)).ravel()


def features(layout: Layout, ch: dict, floor=None, factors: tuple | None = None, noise: bool = True,
             runs: list | None = None) -> Features:
    """Features of the views ``ch`` (whole-record arrays) over ``layout``.

    ``floor`` (per view of ``layout.views``, in the view's unit) is the smallest white noise
    level assumed per sample: a channel logged without noise, or a model that reproduces itself
    to round-off, would otherwise get an infinite weight. It is added to every covariance.
    ``factors`` (``(bins, dc)`` per view) replace the period-to-period factors of a periodic
    frame (e.g. those of a longer segment of the same record). ``noise=False`` computes the
    values only (covariances empty): what a fit's replays need, whose whitener is fixed.
    ``runs`` (view dicts of the replays whose mean ``ch`` is): the ``band`` features are those
    of their mean density (the density of a mean of replays holds a fraction of their noise).
    """
    fr = layout.frame
    seg = slice(fr.i0, fr.i0 + fr.n)
    x = _stack(layout, ch, seg)
    fl2 = np.zeros(len(layout.views)) if floor is None else np.asarray(floor, float) ** 2
    xs = [_stack(layout, r, seg) for r in runs] if runs else [x]
    if not noise:
        f = _values(layout, x, seg)
    elif fr.periodic:
        f = _periodic(layout, x, fl2, factors)
    else:
        f = _welch(layout, x, seg, fl2)
    import dataclasses

    extra = {}
    if layout.n_win:
        extra["win"] = _win_values(layout, x)
        if noise:
            extra["cov_win"] = np.repeat(_low_noise(layout, x, seg)[None] / layout.win_len, layout.n_win - 1, axis=0) \
                + np.diag(fl2 / layout.win_len)[None]
    if layout.bands:
        vals, cov = _band_values(layout, xs, noise)
        extra["band"] = vals
        if noise:
            extra["cov_band"] = cov
    if layout.dl_views:
        xd = np.stack([np.asarray(ch[v], float)[seg] for v in layout.dl_views])
        extra["dl"] = line_phasors(fr, xd, layout.dl_hz)
        if noise:
            extra["cov_dl"] = _dl_noise(layout, xd)
    return dataclasses.replace(f, **extra) if extra else f


def low_frequency_from(f: Features, layout: Layout, longer: Features, n_longer: int) -> Features:
    r"""``f`` with the low-frequency noise (``dc``, ``win``) of a longer periodic segment of the
    same record.

    A sum of :math:`n` samples of stationary noise has variance :math:`n G` with
    :math:`G = f_s S(0^+)/2`; the longer segment's DC covariance gives :math:`G = C_{dc}/n_{longer}`
    (its off-grid bins nearest DC, a fraction of the excitation's resolution away), and ``f``
    takes :math:`n G` for its DC and :math:`G/L` for its window means. A segment of a periodic
    record too short to hold two periods is a Welch frame whose lowest bins lie at
    :math:`f_s/n_{per}` and above, where a loop with integral action has far more noise than at
    DC: its own estimate would overstate the DC noise and hide a static load there.
    """
    import dataclasses

    g = np.asarray(longer.cov_dc, float) / float(n_longer)
    out = {"cov_dc": g * layout.frame.n}
    if layout.n_win and f.cov_win.size:
        out["cov_win"] = np.repeat((g / layout.win_len)[None], layout.n_win - 1, axis=0)
    return dataclasses.replace(f, **out)


def _dl_noise(layout: Layout, xd: np.ndarray) -> np.ndarray:
    """Noise covariance of the ``dl`` phasors: the band covariance of the neighbouring bins that
    carry no deterministic response (off-grid of a periodic frame; the Hann-tapered DFT's band
    otherwise, scaled to a rectangular fit's phasor), plus the views' floors as white noise."""
    fr = layout.frame
    fl2 = np.asarray(layout.dl_floor, float) ** 2
    if fr.periodic:
        X = sfft.rfft(xd, axis=1)
        usable = fr.noise_mask.copy()
        usable[0] = False
        C = _band_cov(X, usable)
        scale = 1.0
    else:
        X = sfft.rfft(xd * fr.window, axis=1)
        C = _band_cov(X, np.ones(X.shape[1], bool))
        scale = fr.n / fr.w2
    kl = [min(int(round(f / fr.df_hz)), X.shape[1] - 1) for f in layout.dl_hz]
    return C[kl] * scale + np.diag(fr.n * fl2)[None]


def _values(layout: Layout, x: np.ndarray, seg: slice) -> Features:
    """The feature values of :func:`_periodic` or :func:`_welch`, without their noise."""
    fr = layout.frame
    empty = np.zeros((0,))
    if fr.periodic:
        X = sfft.rfft(x, axis=1)
        lines = line_phasors(fr, x, layout.lines_hz, X)
        return Features(np.real(X[:, 0]), X[:, layout.bins].T, lines, empty, empty, empty)
    lines = line_phasors(fr, x, layout.lines_hz)
    return Features(x.sum(axis=1), _cross_spectra(layout, x, seg)[0], lines, empty, empty, empty)


def _cross_spectra(layout: Layout, x: np.ndarray, seg: slice) -> tuple:
    """Welch cross-spectra of the views with each excited axis at the layout's bins, ``(F (A, K, V),
    Y (segments, V, K), Sa (segments, A, K))``."""
    nper, kb = layout.nperseg, layout.bins
    Y = _welch_segments(x, nper)[:, :, kb]
    if not layout.axes:                   # nothing excited (levitation at rest): no cross-spectra
        return np.zeros((0, len(kb), x.shape[0]), complex), Y, np.zeros((Y.shape[0], 0, len(kb)), complex)
    Sa = np.stack([layout.excitation_segments(a, seg, nper)[:, kb] for a in layout.axes], axis=1)
    return np.einsum("svk,sak->akv", Y, Sa.conj()) / Y.shape[0], Y, Sa


def _low_noise(layout: Layout, x: np.ndarray, seg: slice, bins=(1, 2, 3)) -> np.ndarray:
    r"""Low-frequency noise of the views, :math:`G = f_s S(0^+)/2` (V x V: a sum of :math:`L`
    samples has covariance :math:`L G`), from the lowest Welch bins with what the excitations
    drive there regressed out across segments (nothing to regress when nothing is excited)."""
    nper = layout.nperseg or _welch_length(layout.frame.n)
    Yall = _welch_segments(x, nper)
    kb = [k for k in bins if k < Yall.shape[2]]
    axes = [a for a in layout.axes if np.ptp(layout.signals[a][seg]) > 0]
    Sall = [layout.excitation_segments(a, seg, nper) for a in axes]
    n_seg = Yall.shape[0]
    G = np.zeros((x.shape[0], x.shape[0]))
    for k in kb:
        Y = Yall[:, :, k]
        if axes and n_seg > len(axes) + 1:
            A = np.stack([s[:, k] for s in Sall], axis=1)
            coef, *_ = np.linalg.lstsq(A, Y, rcond=None)
            R = Y - A @ coef
            G += np.real(R.T @ R.conj()) / (n_seg - len(axes))
        else:
            G += np.real(Y.T @ Y.conj()) / n_seg
    w2 = float(np.sum(signal.windows.hann(nper, sym=False) ** 2))
    return G / max(len(kb), 1) / w2


def _periodic(layout: Layout, x: np.ndarray, fl2: np.ndarray, factors: tuple | None) -> Features:
    fr = layout.frame
    X = sfft.rfft(x, axis=1)
    # the noise is read without the lines the excitation lacks (their leakage is not noise)
    Xn = sfft.rfft(x - _line_components(fr, x, layout.lines_hz), axis=1) if layout.lines_hz else X
    usable = fr.noise_mask.copy()
    usable[0] = False
    C = _band_cov(Xn, usable)
    low = np.flatnonzero(usable)[: max(3, min(8, fr.n // fr.n_period - 1))]
    Z = Xn[:, low]
    cov_dc = np.real(Z @ Z.conj().T) / max(len(low), 1)
    kl = [min(int(round(f / fr.df_hz)), X.shape[1] - 1) for f in layout.lines_hz]
    f = Features(dc=np.real(X[:, 0]), bins=X[:, layout.bins].T, lines=line_phasors(fr, x, layout.lines_hz, X),
                 cov_dc=cov_dc + np.diag(fr.n * fl2), cov_bins=C[layout.bins] + np.diag(fr.n * fl2)[None],
                 cov_lines=(C[kl] if kl else np.zeros((0,) + C.shape[1:])) + np.diag(fr.n * fl2)[None])
    if factors is None:
        factors = _period_factors(layout, x, np.real(np.einsum("kvv->kv", f.cov_bins)), np.diag(f.cov_dc))
    return scale_views(f, *factors[:2])


def _welch_segments(x: np.ndarray, nper: int) -> np.ndarray:
    """Hann-windowed DFTs of half-overlapping segments: (segments, rows, bins)."""
    v = np.moveaxis(sliding_window_view(x, nper, axis=-1)[..., ::nper // 2, :], -2, 0)
    d = v - v.mean(axis=-1, keepdims=True)
    d *= _hann(nper)                      # in place: one temporary array less
    return sfft.rfft(d, axis=-1)


@functools.lru_cache(maxsize=16)
def _hann(nper: int) -> np.ndarray:
    """The periodic Hann window of ``nper`` samples (read-only: shared by every call)."""
    w = signal.windows.hann(nper, sym=False)
    w.flags.writeable = False
    return w


def _welch(layout: Layout, x: np.ndarray, seg: slice, fl2: np.ndarray) -> Features:
    fr, nper, kb = layout.frame, layout.nperseg, layout.bins
    # nothing excited (levitation at rest): no cross-spectra, A = 0
    F, Y, Sa = _cross_spectra(layout, x, seg)                         # A x K x V; S x V x K; S x A x K
    n_seg = Y.shape[0]
    k_eff = max(1.0, n_seg / 1.06)                                    # Hann, 50 % overlap
    # per bin, the noise: residual of the regression of Y on the excitations across segments
    Cn = np.zeros((len(kb), x.shape[0], x.shape[0]), complex)
    for j in range(len(kb)):
        A = Sa[:, :, j]
        coef, *_ = np.linalg.lstsq(A, Y[:, :, j], rcond=None)
        R = Y[:, :, j] - A @ coef
        Cn[j] = R.T @ R.conj() / max(n_seg - A.shape[1], 1)
    Cn = _smooth_cov(Cn) + np.diag(fl2 * np.sum(signal.windows.hann(nper, sym=False) ** 2))[None]
    s2 = np.mean(np.abs(Sa) ** 2, axis=0)                             # A x K
    cov = Cn[None] * (s2[:, :, None, None] / k_eff)
    # variance of a sum of n samples ~ n fs S(0+)/2 (one-sided PSD at the lowest bins, without
    # what the excitation drives there)
    cov_dc = _low_noise(layout, x, seg) * fr.n + np.diag(fr.n * fl2)
    lines = line_phasors(fr, x, layout.lines_hz)
    if layout.lines_hz:
        Xf = sfft.rfft(x * fr.window, axis=1)
        Cl = _band_cov(Xf, np.ones(Xf.shape[1], bool))
        kl = [min(int(round(f / fr.df_hz)), Xf.shape[1] - 1) for f in layout.lines_hz]
        cov_lines = Cl[kl] * (fr.n / fr.w2) + np.diag(fr.n * fl2)[None]
    else:
        cov_lines = np.zeros((0, x.shape[0], x.shape[0]), complex)
    return Features(dc=x.sum(axis=1), bins=F, lines=lines, cov_dc=cov_dc, cov_bins=cov, cov_lines=cov_lines)


def _smooth_cov(C: np.ndarray, half: int = 2) -> np.ndarray:
    """Average per-bin covariances over +-``half`` neighbouring bins (more degrees of freedom)."""
    out = np.empty_like(C)
    for j in range(len(C)):
        out[j] = C[max(j - half, 0):j + half + 1].mean(axis=0)
    return out


def _whitening(C: np.ndarray, ridge: float) -> np.ndarray:
    r"""A matrix :math:`W` with :math:`W C W^H = I` for a covariance regularised relative to its
    own diagonal: :math:`C' = D^{-1} C D^{-1} + \epsilon I`, :math:`D = \mathrm{diag}(\sqrt{C_{vv}})`
    (views in different units), :math:`W = L^{-1} D^{-1}` with :math:`C' = L L^H`."""
    d = np.sqrt(np.maximum(np.real(np.diag(C)), 1e-300))
    Cn = C / np.outer(d, d) + ridge * np.eye(len(d))
    L = np.linalg.cholesky(Cn)
    return np.linalg.solve(L, np.diag(1.0 / d))


@dataclass
class Whitener:
    r"""Turns differences of features into real vectors of unit covariance.

    Built from the covariances of the two feature sets compared (their sum, for independent
    noise), or of one (the other noiseless). ``ridge`` bounds the condition number of the
    normalised covariance (views whose noise is nearly collinear would otherwise give one
    direction an enormous weight).

    The vector is ``[dc (V), Re/Im of bins (2 x K x V), Re/Im of lines (2 x L x V), win ((W-1) x
    V), band (B x Vb), Re/Im of dl (2 x Ld x Vd)]``, with the complex parts scaled by
    :math:`\sqrt 2` (each has half the variance).
    """

    W_dc: np.ndarray
    W_bins: np.ndarray
    W_lines: np.ndarray
    labels: list
    W_win: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    W_band: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    W_dl: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0), complex))

    @classmethod
    def build(cls, layout: Layout, fa: Features, fb: Features | None = None, ridge: float = 1e-3) -> "Whitener":
        """The whitener of ``fa - fb`` (``fb`` None: of ``fa`` alone, the other side noiseless)."""
        def tot(a, b):
            return a if b is None else a + b
        # DC: per view (its cross-view covariance rests on a handful of low bins; a large DC
        # residual in one view, a static load's, must not leak into the others' whitened entries)
        W_dc = _whitening(np.diag(np.diag(tot(fa.cov_dc, None if fb is None else fb.cov_dc))), ridge)
        cb = tot(fa.cov_bins, None if fb is None else fb.cov_bins)
        W_bins = np.array([_whitening(c, ridge) for c in cb.reshape((-1,) + cb.shape[-2:])]).reshape(cb.shape)
        cl = tot(fa.cov_lines, None if fb is None else fb.cov_lines)
        W_lines = np.array([_whitening(c, ridge) for c in cl]).reshape(cl.shape)
        cw = tot(fa.cov_win, None if fb is None else fb.cov_win)
        W_win = np.array([_whitening(c, ridge) for c in cw]).reshape(cw.shape)
        cd = tot(fa.cov_band, None if fb is None else fb.cov_band)
        W_band = np.array([_whitening(c, ridge) for c in cd]).reshape(cd.shape)
        cdl = tot(fa.cov_dl, None if fb is None else fb.cov_dl)
        W_dl = np.array([_whitening(c, ridge) for c in cdl]).reshape(cdl.shape)
        return cls(W_dc, W_bins, W_lines, _labels(layout, cb.shape), W_win, W_band, W_dl)

    def residual(self, fa: Features, fb: Features) -> np.ndarray:
        """Whitened ``fa - fb`` (see class docstring)."""
        out = [self.W_dc @ (fa.dc - fb.dc)]
        e = fa.bins - fb.bins
        w = np.einsum("...ij,...j->...i", self.W_bins, e).ravel()
        out += [math.sqrt(2) * w.real, math.sqrt(2) * w.imag]
        if len(self.W_lines):
            wl = np.einsum("lij,lj->li", self.W_lines, fa.lines - fb.lines).ravel()
            out += [math.sqrt(2) * wl.real, math.sqrt(2) * wl.imag]
        if len(self.W_win):
            out.append(np.real(np.einsum("kij,kj->ki", self.W_win, fa.win - fb.win)).ravel())
        if len(self.W_band):
            out.append(np.real(np.einsum("kij,kj->ki", self.W_band, fa.band - fb.band)).ravel())
        if len(self.W_dl):
            wd = np.einsum("lij,lj->li", self.W_dl, fa.dl - fb.dl).ravel()
            out += [math.sqrt(2) * wd.real, math.sqrt(2) * wd.imag]
        return np.concatenate(out)

    def groups(self) -> dict:
        """Index arrays of the vector per group: ``dc``, ``bins``, ``lines``, ``win``, ``band``,
        ``dl`` and per view."""
        lab = self.labels
        out = {"dc": [], "bins": [], "lines": [], "win": [], "band": [], "dl": []}
        for i, (g, v, _f) in enumerate(lab):
            out[g].append(i)
            out.setdefault("view:" + v, []).append(i)
        return {k: np.asarray(v, int) for k, v in out.items()}


def _labels(layout: Layout, bins_shape) -> list:
    """``(group, view, frequency or time)`` of every entry of the whitened vector."""
    views = layout.views
    lab = [("dc", v, 0.0) for v in views]
    f = layout.f_bins_hz
    nb = int(np.prod(bins_shape[:-2]))
    per = []
    if layout.nperseg == 0:
        per = [(fk, v) for fk in f for v in views]
    else:
        per = [(fk, v) for _a in layout.axes for fk in f for v in views]
    assert len(per) == nb * len(views)
    for part in (0, 1):
        lab += [("bins", v, float(fk)) for fk, v in per]
    for part in (0, 1):
        lab += [("lines", v, float(fl)) for fl in layout.lines_hz for v in views]
    lab += [("win", v, float(j)) for j in range(1, layout.n_win) for v in views]
    lab += [("band", v, float(fb)) for fb in layout.f_bands_hz for v in layout.band_views]
    for part in (0, 1):
        lab += [("dl", v, float(fl)) for fl in layout.dl_hz for v in layout.dl_views]
    return lab
