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
  that all frequency features share one scale.

**Noise.** Each feature comes with the complex covariance across views of its noise,
:math:`C(k) = E[\,\delta X(k)\,\delta X(k)^H]`. For a periodic frame it is the band average of
:math:`X(k)X(k)^H` over the off-grid bins (which hold only what is not synchronous with the
excitation: noise, the self-sensing estimator's pseudo-noise and unrelated lines, whose few
bins a band average barely notices), rescaled per view by the pooled period-to-period spread at
the excited bins when there are enough periods (the estimator's pseudo-noise is cyclostationary:
the off-grid floor can be 10-20 % low at the lines). The DC covariance is that of the lowest
off-grid bins. For a Welch frame the covariance of the residual of a per-bin regression on the
excitation across segments (Bendat & Piersol) gives the noise of the cross-spectra.

The covariance of a **difference** between a measured and a modelled feature is the sum of the
two covariances (independent noise): :class:`Whitener` factors it once and turns any such
difference into a real vector with unit covariance, the currency of every fit and test.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import fft as sfft
from scipy import signal

from .spectra import Frame, _bands

__all__ = ["Features", "Layout", "make_layout", "features", "Whitener", "line_phasors",
           "scale_views", "replicate_factors"]


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
    """

    frame: Frame
    bins: np.ndarray
    axes: tuple
    nperseg: int
    lines_hz: tuple
    views: tuple = ()
    signals: dict = field(default_factory=dict, repr=False)
    device: object = field(default=None, repr=False, compare=False)

    @property
    def f_bins_hz(self) -> np.ndarray:
        fs = self.frame.fs_hz
        return self.bins * fs / (self.frame.n if self.nperseg == 0 else self.nperseg)

    def with_lines(self, lines_hz) -> "Layout":
        """The same layout with other line frequencies."""
        import dataclasses

        return dataclasses.replace(self, lines_hz=tuple(float(f) for f in lines_hz))


def make_layout(frame: Frame, signals: dict, lines_hz=(), views=(), max_bins: int = 64, device=None) -> Layout:
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
    """
    if frame.periodic:
        kb = np.unique(np.concatenate([np.asarray(v, int) for v in frame.excited.values()])) if frame.excited else \
            np.zeros(0, int)
        return Layout(frame, kb, (), 0, tuple(float(f) for f in lines_hz), tuple(views), device=device)
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
    return Layout(frame, cand, tuple(signals), nper, tuple(float(f) for f in lines_hz), tuple(views),
                  {a: np.asarray(s, float) for a, s in signals.items()}, device)


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
    ``cov_lines`` (L, V, V). ``factors`` are the per-view ``(bins, dc)`` factors applied to the
    off-grid covariances (:func:`_period_factors`), to reuse on another segment of the record.
    """

    dc: np.ndarray
    bins: np.ndarray
    lines: np.ndarray
    cov_dc: np.ndarray
    cov_bins: np.ndarray
    cov_lines: np.ndarray
    factors: tuple = ()


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


def scale_views(f: "Features", fac_bins: np.ndarray, fac_dc: np.ndarray) -> "Features":
    r"""The features with their noise covariances scaled per view (``C -> D C D``,
    :math:`D = \mathrm{diag}\sqrt{\mathrm{fac}}`; lines take the bins' factors)."""
    import dataclasses

    d, e = np.sqrt(fac_bins), np.sqrt(fac_dc)
    return dataclasses.replace(f, cov_bins=f.cov_bins * d[:, None] * d[None, :],
                               cov_lines=f.cov_lines * d[:, None] * d[None, :], cov_dc=f.cov_dc * np.outer(e, e),
                               factors=(np.asarray(fac_bins), np.asarray(fac_dc)))


def replicate_factors(fs: list) -> tuple[np.ndarray, np.ndarray]:
    r"""Per-view factors from replicates: the features of ``m`` replays with distinct seeds.

    Bins: the median over bins of the replicates' variance over the predicted (off-grid)
    variance of one replay, corrected for the median of :math:`\chi^2_{2(m-1)}/(2(m-1))`; DC:
    the replicates' variance over the predicted one. Never below 1: a replay's own noise is at
    least what its off-grid bins show (the self-sensing estimator's pseudo-noise and the
    current loops' drift add to it at the lines and at DC).
    """
    m = len(fs)
    if m < 3:
        nv = fs[0].dc.shape[-1]
        return np.ones(nv), np.ones(nv)
    B = np.array([f.bins for f in fs])
    emp = np.sum(np.abs(B - B.mean(axis=0)) ** 2, axis=0) / (m - 1)
    pred = np.mean([np.real(np.einsum("...vv->...v", f.cov_bins)) for f in fs], axis=0)
    nu = 2 * (m - 1)
    med = (1 - 2 / (9 * nu)) ** 3
    ratio = (emp / np.maximum(pred, 1e-300)).reshape(-1, emp.shape[-1])
    # no excited bins (levitation at rest): the DC factor stands alone
    fac = np.maximum(np.median(ratio, axis=0) / med, 1.0) if ratio.shape[0] else np.ones(emp.shape[-1])
    D = np.array([f.dc for f in fs])
    pred_dc = np.mean([np.diag(f.cov_dc) for f in fs], axis=0)
    fac_dc = np.maximum(D.var(axis=0, ddof=1) / np.maximum(pred_dc, 1e-300), fac)
    return fac, fac_dc


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


def features(layout: Layout, ch: dict, floor=None, factors: tuple | None = None, noise: bool = True) -> Features:
    """Features of the views ``ch`` (whole-record arrays) over ``layout``.

    ``floor`` (per view of ``layout.views``, in the view's unit) is the smallest white noise
    level assumed per sample: a channel logged without noise, or a model that reproduces itself
    to round-off, would otherwise get an infinite weight. It is added to every covariance.
    ``factors`` (``(bins, dc)`` per view) replace the period-to-period factors of a periodic
    frame (e.g. those of a longer segment of the same record). ``noise=False`` computes the
    values only (covariances empty): what a fit's replays need, whose whitener is fixed.
    """
    fr = layout.frame
    seg = slice(fr.i0, fr.i0 + fr.n)
    x = _stack(layout, ch, seg)
    fl2 = np.zeros(len(layout.views)) if floor is None else np.asarray(floor, float) ** 2
    if not noise:
        return _values(layout, x, seg)
    if fr.periodic:
        return _periodic(layout, x, fl2, factors)
    return _welch(layout, x, seg, fl2)


def _values(layout: Layout, x: np.ndarray, seg: slice) -> Features:
    """The feature values of :func:`_periodic` or :func:`_welch`, without their noise."""
    fr = layout.frame
    empty = np.zeros((0,))
    if fr.periodic:
        X = sfft.rfft(x, axis=1)
        lines = line_phasors(fr, x, layout.lines_hz, X)
        return Features(np.real(X[:, 0]), X[:, layout.bins].T, lines, empty, empty, empty)
    lines = line_phasors(fr, x, layout.lines_hz)
    nper, kb = layout.nperseg, layout.bins
    if not layout.axes:                   # nothing excited (levitation at rest): no cross-spectra
        return Features(x.sum(axis=1), np.zeros((0, len(kb), x.shape[0]), complex), lines, empty, empty, empty)
    Y = _welch_segments(x, nper)[:, :, kb]
    Sa = np.stack([_welch_segments(layout.signals[a][seg][None, :], nper)[:, 0, kb] for a in layout.axes], axis=1)
    F = np.einsum("svk,sak->akv", Y, Sa.conj()) / Y.shape[0]
    return Features(x.sum(axis=1), F, lines, empty, empty, empty)


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
    return scale_views(f, *factors)


def _welch_segments(x: np.ndarray, nper: int) -> np.ndarray:
    """Hann-windowed DFTs of half-overlapping segments: (segments, rows, bins)."""
    step = nper // 2
    starts = range(0, x.shape[-1] - nper + 1, step)
    w = signal.windows.hann(nper, sym=False)
    segs = np.stack([x[..., s:s + nper] - x[..., s:s + nper].mean(axis=-1, keepdims=True) for s in starts])
    return sfft.rfft(segs * w, axis=-1)


def _welch(layout: Layout, x: np.ndarray, seg: slice, fl2: np.ndarray) -> Features:
    fr, nper, kb = layout.frame, layout.nperseg, layout.bins
    nv = x.shape[0]
    if layout.axes:
        Y = _welch_segments(x, nper)[:, :, kb]                        # S x V x K
        Sa = np.stack([_welch_segments(layout.signals[a][seg][None, :], nper)[:, 0, kb] for a in layout.axes], axis=1)
        n_seg = Y.shape[0]
        k_eff = max(1.0, n_seg / 1.06)                                # Hann, 50 % overlap
        F = np.einsum("svk,sak->akv", Y, Sa.conj()) / n_seg           # A x K x V
        # per bin, the noise: residual of the regression of Y on the excitations across segments
        Cn = np.zeros((len(kb), nv, nv), complex)
        for j in range(len(kb)):
            A = Sa[:, :, j]
            coef, *_ = np.linalg.lstsq(A, Y[:, :, j], rcond=None)
            R = Y[:, :, j] - A @ coef
            Cn[j] = R.T @ R.conj() / max(n_seg - A.shape[1], 1)
        Cn = _smooth_cov(Cn) + np.diag(fl2 * np.sum(signal.windows.hann(nper, sym=False) ** 2))[None]
        s2 = np.mean(np.abs(Sa) ** 2, axis=0)                         # A x K
        cov = Cn[None] * (s2[:, :, None, None] / k_eff)
    else:                                 # nothing excited (levitation at rest): no cross-spectra
        F = np.zeros((0, len(kb), nv), complex)
        cov = np.zeros((0, len(kb), nv, nv), complex)
    x0 = x - x.mean(axis=1, keepdims=True)
    f, P = signal.csd(x0[:, None, :], x0[None, :, :], fs=fr.fs_hz, nperseg=nper, noverlap=nper // 2, window="hann",
                      detrend="constant", axis=-1)
    # variance of a sum of n samples ~ n fs S(0+)/2 (one-sided PSD at the lowest bins)
    cov_dc = np.real(np.mean(P[:, :, 1:4], axis=-1)) * fr.n * fr.fs_hz / 2.0 + np.diag(fr.n * fl2)
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

    The vector is ``[dc (V), Re/Im of bins (2 x K x V), Re/Im of lines (2 x L x V)]``, with the
    complex parts scaled by :math:`\sqrt 2` (each has half the variance).
    """

    W_dc: np.ndarray
    W_bins: np.ndarray
    W_lines: np.ndarray
    labels: list

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
        return cls(W_dc, W_bins, W_lines, _labels(layout, cb.shape))

    def residual(self, fa: Features, fb: Features) -> np.ndarray:
        """Whitened ``fa - fb`` (see class docstring)."""
        out = [self.W_dc @ (fa.dc - fb.dc)]
        e = fa.bins - fb.bins
        w = np.einsum("...ij,...j->...i", self.W_bins, e).ravel()
        out += [math.sqrt(2) * w.real, math.sqrt(2) * w.imag]
        if len(self.W_lines):
            wl = np.einsum("lij,lj->li", self.W_lines, fa.lines - fb.lines).ravel()
            out += [math.sqrt(2) * wl.real, math.sqrt(2) * wl.imag]
        return np.concatenate(out)

    def groups(self) -> dict:
        """Index arrays of the vector per group: ``dc``, ``bins``, ``lines`` and per view."""
        lab = self.labels
        out = {"dc": [], "bins": [], "lines": []}
        for i, (g, v, _f) in enumerate(lab):
            out[g].append(i)
            out.setdefault("view:" + v, []).append(i)
        return {k: np.asarray(v, int) for k, v in out.items()}


def _labels(layout: Layout, bins_shape) -> list:
    """``(group, view, frequency)`` of every entry of the whitened vector."""
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
    return lab
