r"""Frequency-domain tools: DFT frames, noise floor, lines, offsets, transfer estimates.

Notation: a segment of :math:`n` samples :math:`x_m` with taper :math:`w_m` has the DFT

.. math:: X(k) = \sum_{m=0}^{n-1} w_m x_m e^{-2\pi j k m / n}, \qquad f_k = k f_s / n .

For white noise of variance :math:`\sigma^2`, :math:`E|X(k)|^2 = \sigma^2 W_2` with
:math:`W_2 = \sum w_m^2`, and :math:`|X(k)|^2` is exponentially distributed. The **noise
floor** :math:`S(k) = E|X(k)|^2` is estimated by the median of :math:`|X|^2` over the bins of
a frequency band that carry no excitation, divided by :math:`\ln 2` (the median of an
exponential variable); its white-equivalent variance is
:math:`\hat\sigma^2 = \frac{2}{n W_2}\sum_{k \ge 1} S(k)`.

Periodic excitation (a multisine recorded over whole periods, rectangular taper): every
deterministic response to it, including harmonics, intermodulation and the PWM sampling
pattern, lies on the **grid** :math:`k = iP` (:math:`P` periods in the segment); the bins
between carry only noise and disturbances that are not synchronous with the excitation. The
noise floor uses the off-grid bins, lines the excitation lacks are searched there, and the
excited lines are read exactly, without leakage. Other excitations use a Hann taper, and the
noise floor uses the bins where the excitation has little power.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, signal

__all__ = ["Frame", "make_frame", "dft", "noise_floor", "white_sigma", "find_peaks_bins", "lasts",
           "fit_line", "line_drift", "offset", "welch_transfer"]


@dataclass(frozen=True)
class Frame:
    """Frequency bookkeeping of one analysis segment.

    Attributes
    ----------
    fs_hz : float
    i0, n : int
        First sample (absolute index in the record) and length of the segment.
    window : numpy.ndarray
        Taper (ones when periodic).
    w2 : float
        :math:`\\sum w^2`.
    f_hz : numpy.ndarray
        Bin frequencies.
    periodic : bool
    n_period : int or None
    noise_mask : numpy.ndarray of bool
        Bins usable for the noise floor.
    grid_mask : numpy.ndarray of bool
        Periodic grid (periodic frames), else the bins with excitation power.
    line_mask : numpy.ndarray of bool
        Bins where lines the excitation lacks are searched: every bin but DC and the excited
        lines (periodic frames: unexcited grid bins included), else away from the excitation's
        own narrow lines that last through the segment (a broadband excitation excludes none).
    passing_mask : numpy.ndarray of bool or None
        Non-periodic frames: the bins of the excitation's own narrow lines that do not last
        through the segment (the range a sweep passes once). A line the excitation lacks is
        searched there too, but counts only if it lasts itself (:func:`lasts`): a sweep's
        passage through a misfit resonance leaves a transient, an unbalance spins throughout.
    excited : dict
        Per excited axis, the bin indices of the excited lines (periodic frames).
    """

    fs_hz: float
    i0: int
    n: int
    window: np.ndarray
    w2: float
    f_hz: np.ndarray
    periodic: bool
    n_period: int | None
    noise_mask: np.ndarray
    grid_mask: np.ndarray
    excited: dict
    line_mask: np.ndarray
    passing_mask: np.ndarray | None = None

    @property
    def df_hz(self) -> float:
        return self.fs_hz / self.n

    @property
    def t_s(self) -> np.ndarray:
        return (self.i0 + np.arange(self.n)) / self.fs_hz


def make_frame(fs_hz: float, i0: int, n: int, excitation: dict, n_period: int | None,
               lines_hz: np.ndarray | None) -> Frame:
    """Frame of the segment ``[i0, i0 + n)``.

    Parameters
    ----------
    excitation : dict
        Per excited axis, the excitation signal over the whole record.
    n_period : int or None
        Samples per period of a periodic excitation (``n`` must then be a multiple of it).
    lines_hz : array or None
        Excited lines of a multisine (else they are found from the excitation's DFT).
    """
    f = np.fft.rfftfreq(n, 1.0 / fs_hz)
    nb = len(f)
    k = np.arange(nb)
    excited = {}
    if n_period is not None and n % n_period == 0 and n // n_period >= 2:
        per = n // n_period
        window = np.ones(n)
        grid = (k % per) == 0
        noise = ~grid
        for ax, s in excitation.items():
            S = np.fft.rfft(s[i0:i0 + n])
            if lines_hz is not None and len(lines_hz):
                kb = np.unique(np.round(np.asarray(lines_hz) * n / fs_hz).astype(int))
                kb = kb[(kb > 0) & (kb < nb)]
            else:
                mag = np.abs(S) * grid
                kb = np.flatnonzero(mag > 1e-6 * mag.max()) if mag.max() > 0 else np.array([], int)
                kb = kb[kb > 0]
            excited[ax] = kb
        # lines are searched everywhere but at DC and the excited lines: a rotating force at a
        # harmonic of the excitation period sits on the grid (a round speed under a 1 Hz multisine)
        line = np.ones(nb, bool)
        line[0] = False
        for kb in excited.values():
            line[kb] = False
        return Frame(fs_hz, i0, n, window, float(n), f, True, n_period, noise, grid, excited, line)
    window = signal.windows.hann(n, sym=False)
    pw = np.zeros(nb)
    for s in excitation.values():
        pw = np.maximum(pw, np.abs(np.fft.rfft(window * (s[i0:i0 + n] - np.mean(s[i0:i0 + n])))) ** 2)
    exc_mask = pw > 1e-4 * pw.max() if pw.max() > 0 else np.zeros(nb, bool)
    # narrow lines of the excitation itself: 100 x above its local (banded) median; those that do
    # not last through the segment (a sweep's range stands as narrow against a wide band's
    # median, but the sweep passes each frequency once) are searched, for lines that last
    exc_lines = np.zeros(nb, bool)
    passing = np.zeros(nb, bool)
    if pw.max() > 0:
        for a, b in _bands(np.ones(nb, bool), 64, 32):
            med = np.median(pw[a:b])
            exc_lines[a:b] = (pw[a:b] > 100.0 * max(med, 1e-300)) & (pw[a:b] > 1e-8 * pw.max())
        lasting = _lasting(fs_hz, i0, n, excitation, f)
        main_lobe = np.ones(5)      # the Hann window's main lobe
        passing = np.convolve((exc_lines & ~lasting).astype(float), main_lobe, mode="same") > 0
        exc_lines = np.convolve((exc_lines & lasting).astype(float), main_lobe, mode="same") > 0
        passing &= ~exc_lines
    return Frame(fs_hz, i0, n, window, float(np.sum(window ** 2)), f, False, None, ~exc_mask,
                 exc_mask, excited, ~exc_lines, passing)


def _lasting(fs_hz: float, i0: int, n: int, excitation: dict, f_hz: np.ndarray, parts: int = 4,
             share: float = 0.1) -> np.ndarray:
    r"""Bins (of ``f_hz``) where some axis' excitation lasts through the segment ``[i0, i0 + n)``:
    in each of ``parts`` equal parts (Hann-tapered, their coarser bins mapped to the nearest)
    its power is at least ``share`` of its largest part's. A multisine's line lasts; a sweep
    passes each frequency in one part, where the others hold only leakage. Below two of the
    parts' bins they cannot tell: counted as lasting."""
    q = n // parts
    out = np.zeros(len(f_hz), bool)
    if q < 8:
        return ~out
    w = signal.windows.hann(q, sym=False)
    k = np.minimum(np.round(f_hz * q / fs_hz).astype(int), q // 2)
    for s in excitation.values():
        seg = np.asarray(s[i0:i0 + parts * q], float)
        p = np.array([np.abs(np.fft.rfft(w * (x - np.mean(x)))) ** 2 for x in seg.reshape(parts, q)])
        out |= (p.min(axis=0) >= share * p.max(axis=0))[k] & (p.max(axis=0)[k] > 0)
    return out | (k < 2)


def lasts(frame: Frame, x: np.ndarray, f_hz: float, parts: int = 4, max_ratio: float = 10.0) -> bool:
    r"""Does a line at ``f_hz`` last through the frame's segment ``x`` (the segment's samples)?

    The segment is cut into ``parts`` equal parts; in each, the power of ``x`` at ``f_hz``
    (Hann-tapered quadrature sums) :math:`P_q`. A line that spins throughout puts about the same
    power in every part; a transient (a sweep passing a resonance the model misplaces) puts it in
    one. The line lasts when the largest part holds at most ``max_ratio`` times the mean of the
    others: at the detection threshold a steady line has a signal-to-noise ratio of about 4 per
    part, whose largest-to-others ratio stays below 10, while a transient detected in the whole
    segment stands that far above the others' noise in its own part.
    """
    q = len(x) // parts
    if q < 8:
        return True
    w = signal.windows.hann(q, sym=False)
    t = (frame.i0 + np.arange(parts * q)) / frame.fs_hz
    e = np.exp(-2j * np.pi * f_hz * t).reshape(parts, q)
    xs = np.asarray(x[: parts * q], float).reshape(parts, q)
    p = np.abs(np.sum(w * (xs - xs.mean(axis=1, keepdims=True)) * e, axis=1)) ** 2
    top = int(np.argmax(p))
    rest = float(np.mean(np.delete(p, top)))
    return bool(p[top] <= max_ratio * rest)


def dft(frame: Frame, x: np.ndarray) -> np.ndarray:
    """DFT of the frame's segment of ``x`` (a whole-record array), tapered."""
    seg = x[frame.i0:frame.i0 + frame.n]
    if not frame.periodic:
        seg = seg - np.mean(seg)
    return np.fft.rfft(frame.window * seg)


def _bands(usable: np.ndarray, n_bands: int, min_bins: int) -> list[tuple[int, int]]:
    nb = len(usable)
    edges = np.unique(np.round(np.geomspace(1, nb, n_bands + 1)).astype(int))
    bands, a, count = [], 1, 0
    for e in edges[1:]:
        count = int(np.count_nonzero(usable[a:e]))
        if count >= min_bins or e >= nb:
            bands.append((a, e))
            a = e
    if not bands:
        bands = [(1, nb)]
    elif bands[-1][1] < nb:
        bands[-1] = (bands[-1][0], nb)
    # merge a last band that is too thin into its neighbour
    if len(bands) > 1 and np.count_nonzero(usable[bands[-1][0]:bands[-1][1]]) < min_bins:
        bands[-2] = (bands[-2][0], bands[-1][1])
        bands.pop()
    return bands


def noise_floor(frame: Frame, X: np.ndarray, n_bands: int = 32, min_bins: int = 24,
                floor: float = 0.0) -> np.ndarray:
    r"""Noise floor :math:`S(k) = E|X(k)|^2` per bin (banded median of the noise bins / ln 2).

    ``floor`` is the smallest white-equivalent noise standard deviation admitted (a channel
    logged without noise would otherwise give :math:`S = 0`).
    """
    P = np.abs(X) ** 2
    nb = len(P)
    usable = frame.noise_mask.copy()
    usable[0] = False
    S = np.empty(nb)
    for a, b in _bands(usable, n_bands, min_bins):
        sel = usable[a:b]
        vals = P[a:b][sel] if np.count_nonzero(sel) >= min_bins // 2 else P[a:b]
        S[a:b] = np.median(vals) / math.log(2.0) if len(vals) else 0.0
    S[0] = S[1] if nb > 1 else 0.0
    return np.maximum(S, floor ** 2 * frame.w2)


def white_sigma(frame: Frame, S: np.ndarray) -> float:
    r"""White-equivalent standard deviation of a noise floor, :math:`\sqrt{\frac{2}{n W_2}\sum_{k\ge1} S(k)}`."""
    return float(math.sqrt(2.0 * np.sum(S[1:]) / (frame.n * frame.w2)))


def offset(frame: Frame, x: np.ndarray, S: np.ndarray) -> tuple[float, float]:
    r"""Mean of the segment and its standard error from the low-frequency noise floor.

    .. math:: \hat\mu = \frac1n\sum x_m, \qquad \mathrm{SE}^2 = \frac{S(0^+)}{n W_2}
    """
    seg = x[frame.i0:frame.i0 + frame.n]
    se = math.sqrt(max(S[1], 0.0) / (frame.n * frame.w2)) if len(S) > 1 else float("nan")
    return float(np.mean(seg)), se


def find_peaks_bins(frame: Frame, P: dict, S: dict, f_lo_hz: float, f_hi_hz: float,
                    alpha: float, exclude_hz: np.ndarray | None = None,
                    half_width_bins: int = 3, local_bins: int = 24) -> list[dict]:
    r"""Bins whose power stands above the noise floor, clustered across views.

    A bin of view :math:`v` is significant when :math:`|X_v(k)|^2 / S_v(k) > \ln(M/\alpha)`
    (:math:`M` = bins x views tested; Bonferroni over the exponential distribution), with
    :math:`S_v` the larger of the noise floor and the running median of :math:`\pm`
    ``local_bins`` bins (over ln 2): a line is narrow, a resonance is not. Returns
    clusters ``{bin, f_hz, views: {view: ratio}}`` sorted by strength.
    """
    f = frame.f_hz
    mask = frame.line_mask & (f >= max(f_lo_hz, 2 * frame.df_hz)) & (f <= f_hi_hz)
    if exclude_hz is not None and len(exclude_hz):
        for fe in np.atleast_1d(exclude_hz):
            mask &= np.abs(f - fe) > (half_width_bins + 0.5) * frame.df_hz
    m_tests = max(int(np.count_nonzero(mask)) * max(len(P), 1), 1)
    thr = math.log(m_tests / alpha)
    hits = {}
    from scipy.ndimage import median_filter

    for v in P:
        # a line is narrow: compare with the running median of its neighbourhood as well (a
        # resonance of a broadband residual is not a line)
        local = median_filter(P[v], size=2 * local_bins + 1, mode="nearest") / math.log(2.0)
        ratio = P[v] / np.maximum(np.maximum(S[v], local), 1e-300)
        idx = np.flatnonzero(mask & (ratio > thr))
        for i in idx:
            lo, hi = max(i - half_width_bins, 0), i + half_width_bins + 1
            if ratio[i] >= np.max(ratio[lo:hi] * mask[lo:hi]):
                hits.setdefault(v, []).append((int(i), float(ratio[i])))
    clusters: list[dict] = []
    for v, lst in hits.items():
        for i, r in lst:
            for c in clusters:
                if abs(c["bin"] - i) <= half_width_bins:
                    c["views"][v] = max(c["views"].get(v, 0.0), r)
                    if r > c["peak"]:
                        c["peak"], c["bin"] = r, i
                    break
            else:
                clusters.append({"bin": i, "peak": r, "views": {v: r}})
    for c in clusters:
        c["f_hz"] = float(f[c["bin"]])
        c["threshold"] = thr
    clusters.sort(key=lambda c: -c["peak"])
    return clusters


def _periodic_project(frame: Frame, x: np.ndarray) -> np.ndarray:
    """Remove the part synchronous with the period (the tiled mean over periods)."""
    if not frame.periodic:
        return x - np.mean(x)
    per = frame.n // frame.n_period
    r = x.reshape(per, frame.n_period)
    return (r - r.mean(axis=0)).ravel()


def fit_line(frame: Frame, segs: dict, sigmas: dict, f0_hz: float, search_bins: float = 1.5,
             max_passes: int = 4) -> dict:
    r"""Refine a line's frequency, with its standard error, and estimate its phasor in every view.

    The frequency maximises the weighted power of the views' best sinusoids,

    .. math:: \hat\omega = \arg\max_\omega \sum_v \frac{\hat e_v^\top H D (D^\top H D)^{-1}
              D^\top H \hat e_v}{s_v^2}, \qquad D = [\cos\omega t,\ \sin\omega t],

    within ``search_bins`` of ``f0_hz`` (time from the start of the record, so the phase is that
    of the record), with the part synchronous with a periodic excitation removed from data and
    regressors alike. :math:`H` is the identity for a periodic frame, whose projection has
    removed the whole response to the excitation (the model's misfit of it included), and the
    Hann taper otherwise: there the residual holds the model's misfit of a broadband excitation,
    often loud below the line, and the taper's sidelobes, falling as :math:`1/k^3` against the
    rectangle's :math:`1/k`, keep it from pulling the frequency. Each view is weighted by its
    noise *near the line*, :math:`s_v = \max(\sigma_v, \hat\sigma_{v,\mathrm{local}})`, the
    tapered residual power (the line removed) of the bins 3-6 resolutions away on the louder
    side: a view whose residual is loud about the line carries less of its frequency, whatever
    its floor elsewhere. The line is removed there at the current frequency, and weights and
    frequency are found in turn (at most ``max_passes`` times, until the frequency moves by less
    than :math:`10^{-4}` of a resolution): a line removed at its detection bin, up to half a
    resolution off, leaves a remainder in those bins that is the louder the stronger the line,
    and would weight the views with the clearest line least.

    ``f_se_hz`` is the estimator's own standard error, the sandwich
    :math:`(A^{-1} B A^{-1})_{\omega\omega}/2\pi` of the weighted least squares in the
    frequency and every view's two amplitudes, with :math:`A = \sum_v J_v^\top H J_v / s_v^2`,
    :math:`B = \sum_v J_v^\top H^2 J_v / s_v^2` (noise white at :math:`s_v` near the line): the
    Cramer-Rao bound (:math:`\frac{\sqrt{12}}{2\pi}\Delta f/\sqrt{\chi^2}`) at the local noise
    untapered, about 1.6 times it with the taper in white noise (the price of the taper).

    The phasor is the untapered least squares at :math:`\hat\omega`, :math:`A_v = a_v - j b_v`
    (so :math:`e_v = \mathrm{Re}\,A_v e^{j\omega t}`); the projection keeps it unbiased by the
    periodic response, and ``component`` is the whole sinusoid (to remove the line everywhere,
    its leakage onto the grid included).

    Parameters
    ----------
    segs : dict
        Per view, the residual over the frame's segment (length ``frame.n``).
    sigmas : dict
        Per view, the white-equivalent noise standard deviation.
    f0_hz : float
        The detected line's frequency (its bin); the search lies within ``search_bins`` of it.
    max_passes : int
        Most alternations of the views' weights and the frequency.
    """
    t = frame.t_s
    k0 = int(round(f0_hz / frame.df_hz))
    on_grid = frame.periodic and abs(f0_hz / frame.df_hz - k0) < 1e-6 and frame.grid_mask[k0]
    if on_grid and not _leaks(frame, segs, sigmas, k0):
        return _grid_line(frame, segs, sigmas, k0)
    names = list(segs)
    proj = {v: _periodic_project(frame, np.asarray(e, float)) for v, e in segs.items()}
    taper = np.ones(frame.n) if frame.periodic else np.hanning(frame.n)

    def design(fh):
        w = 2 * np.pi * fh * t
        return np.column_stack([_periodic_project(frame, np.cos(w)), _periodic_project(frame, np.sin(w))])

    def phasors(fh):
        D = design(fh)
        return D, np.linalg.solve(D.T @ D, D.T @ np.stack([proj[v] for v in names]).T)      # (2, views)

    df = frame.df_hz
    fh = f0_hz
    for _ in range(max_passes):
        s = _line_weights(frame, proj, names, phasors, fh, sigmas, taper)
        Ew = np.stack([proj[v] * taper / s[v] for v in names])

        def power(f):
            D = design(f)
            B = Ew @ D                       # (views, 2)
            return float(np.sum(B * np.linalg.solve(D.T @ (D * taper[:, None]), B.T).T))

        res = optimize.minimize_scalar(lambda f: -power(f), bounds=(f0_hz - search_bins * df, f0_hz + search_bins * df),
                                       method="bounded", options={"xatol": 1e-6 * df + 1e-9})
        moved, fh = abs(float(res.x) - fh), float(res.x)
        if moved < 1e-4 * df:
            break
    s = _line_weights(frame, proj, names, phasors, fh, sigmas, taper)
    D, ab = phasors(fh)
    Ginv = np.linalg.inv(D.T @ D)
    scale = math.sqrt(max(Ginv[0, 0], Ginv[1, 1]))
    out = {"f_hz": fh, "phasor": {}, "se": {}, "chi2": {}, "component": {}, "se_scale": scale,
           "f_se_hz": _frequency_se(t, D, ab, [s[v] for v in names], taper, fh,
                                    lambda x: _periodic_project(frame, x),
                                    _coherence(frame, [proj[v] - D @ ab[:, i] for i, v in enumerate(names)],
                                               fh / frame.df_hz, taper))}
    for i, v in enumerate(names):
        a, b = ab[:, i]
        se = sigmas[v] * scale
        out["phasor"][v] = complex(a, -b)
        out["se"][v] = se
        out["chi2"][v] = float((a * a + b * b) / se ** 2) if se > 0 else float("inf")
        out["component"][v] = a * np.cos(2 * np.pi * fh * t) + b * np.sin(2 * np.pi * fh * t)
    return out


def line_drift(frame: Frame, res: dict, line: dict, f_hz: float, min_line_chi2: float = 100.0) -> dict | None:
    r"""The frequency error of a modelled line, read from the drift of the data's phase against
    the model's line over the frame.

    The model predicts a line :math:`P_v(t)` in view :math:`v` (a rotating unbalance at its
    estimated speed :math:`f`: the model with the effect minus the model without it, so that an
    excitation's own response is no part of it) and the data hold it at :math:`f + \delta`, a
    little larger by :math:`a_v` and ahead by :math:`\varphi_v`. To first order the residual
    (data minus model) is then

    .. math:: R_v(t) = a_v P_v(t) + \left(\varphi_v + 2\pi\delta\,(t - t_c)\right) Q_v(t) + e_v(t),
              \qquad Q_v(t) = P_v\!\left(t + \tfrac{1}{4f}\right),

    :math:`Q_v` the model's line a quarter cycle ahead (its quadrature, the course of its
    envelope kept), :math:`t_c` the frame's centre. Each view's least squares in
    :math:`(a_v, \varphi_v, 2\pi\delta_v)` -- signals and regressors alike with a periodic
    frame's synchronous part removed (:func:`_periodic_project`: the model's misfit of the
    excitation goes, and what the removal does to the line is carried by the regressors) --
    gives :math:`\delta_v` with the variance of white noise at the residual's level near the
    line (:func:`_local_sigma`). A view whose model line does not stand above its own replay
    noise by ``min_line_chi2`` (:math:`|A_v|^2 / \mathrm{var} A_v` of its phasor; a phase
    error of 0.1 rad at 100) is left out: regressors made of noise would pull its estimate to
    zero. The views are pooled with weights :math:`1/\sigma_v^2` and the pooled error is the
    same weighted mean of their errors, the error of views whose noise is one (the views of one
    loop -- position, current, controller output -- carry the same noise near the line), an
    upper bound for any correlation between them: a generalised least squares with their
    correlation estimated near one would weigh their small differences as information.

    Why not the line's frequency in the residual of a model without the line
    (:func:`fit_line`): the model's line is not a stationary sinusoid where the loop's response
    to the force starts or settles (the current loops' and the magnetics' slow states), and the
    data share that course; the regressors built from the model's own line carry it, where a
    sinusoid fitted to it reads it as a frequency. And the features the cost compares hold one
    phasor per line over a part, which a speed error leaves unchanged to first order (the phase
    drifts symmetrically about the part's centre), so that the fitting part's cost cannot find
    the speed, while the held-out part after it sees the whole drift.

    Parameters
    ----------
    frame : Frame
        The segment read.
    res, line : dict
        Per view, the residual and the model's line over the whole record (the quadrature reads
        the line a quarter cycle past the segment's end).
    f_hz : float
        The modelled line's frequency.
    min_line_chi2 : float
        Least strength of a view's model line (above).

    Returns
    -------
    dict or None
        ``delta_hz`` and ``se_hz`` pooled, ``views`` (per view ``delta_hz``, ``se_hz``); None
        when no view holds the line.
    """
    seg = slice(frame.i0, frame.i0 + frame.n)
    t_all = np.arange(len(next(iter(line.values())))) / frame.fs_hz
    t = frame.t_s
    T = t - (frame.i0 + frame.n / 2) / frame.fs_hz
    k0 = f_hz / frame.df_hz
    usable = ~frame.grid_mask if frame.periodic else None
    ones = np.ones(frame.n)
    D = np.column_stack([np.cos(2 * np.pi * f_hz * t), np.sin(2 * np.pi * f_hz * t)])
    D = np.column_stack([_periodic_project(frame, x) for x in D.T])
    Dg = np.linalg.inv(D.T @ D)
    per = {}
    for v in res:
        if v not in line:
            continue
        P = np.asarray(line[v], float)
        p_seg = _periodic_project(frame, P[seg])
        ab = Dg @ (D.T @ p_seg)
        s_p = _local_sigma(p_seg - D @ ab, k0, ones, usable=usable)
        if not float(ab @ np.linalg.solve(Dg, ab)) > min_line_chi2 * s_p ** 2:
            continue
        Q = np.interp(t + 0.25 / f_hz, t_all, P)
        X = np.column_stack([p_seg, _periodic_project(frame, Q), _periodic_project(frame, T * Q)])
        G = X.T @ X
        y = _periodic_project(frame, np.asarray(res[v], float)[seg])
        beta = np.linalg.solve(G, X.T @ y)
        s_r = _local_sigma(y - X @ beta, k0, ones, usable=usable)
        se = s_r * math.sqrt(np.linalg.inv(G)[2, 2]) / (2 * np.pi)
        if se > 0 and math.isfinite(se):
            per[v] = {"delta_hz": float(beta[2] / (2 * np.pi)), "se_hz": float(se)}
    if not per:
        return None
    d = np.array([x["delta_hz"] for x in per.values()])
    w = 1.0 / np.array([x["se_hz"] for x in per.values()]) ** 2
    w = w / w.sum()
    return {"delta_hz": float(w @ d), "se_hz": float(w @ np.array([x["se_hz"] for x in per.values()])),
            "views": per}


def _line_weights(frame: Frame, proj: dict, names: list, phasors, fh: float, sigmas: dict,
                  taper: np.ndarray) -> dict:
    r"""Per view, :math:`s_v = \max(\sigma_v, \hat\sigma_{v,\mathrm{local}})` with the line
    removed at ``fh`` (:func:`fit_line`)."""
    D, ab = phasors(fh)
    usable = ~frame.grid_mask if frame.periodic else None
    return {v: max(sigmas[v], _local_sigma(proj[v] - D @ ab[:, i], fh / frame.df_hz, taper, usable=usable))
            for i, v in enumerate(names)}


def _local_sigma(r: np.ndarray, k0: float, taper: np.ndarray, inner: int = 3, outer: int = 6,
                 usable: np.ndarray | None = None) -> float:
    r"""White-equivalent standard deviation of ``r`` near bin ``k0``: the mean tapered power
    :math:`|X(k)|^2 / W_2` over the bins :math:`3 \le \pm(k - k_0) \le 6` (beyond the taper's main
    lobe, where a line's remainder would sit), the louder side: noise that falls steeply with
    frequency reaches the line through the taper from below. ``usable`` excludes bins (a periodic
    frame's grid, which its projection has emptied)."""
    P = np.abs(np.fft.rfft(taper * r)) ** 2
    k = np.arange(len(P))
    ok = (k >= 1) if usable is None else (k >= 1) & usable[:len(P)]
    sides = [P[(s * (k - k0) >= inner) & (s * (k - k0) <= outer) & ok] for s in (-1, 1)]
    means = [float(np.mean(x)) for x in sides if len(x)]
    return float(math.sqrt(max(means) / np.sum(taper ** 2))) if means else 0.0


def _coherence(frame: Frame, res: list, k0: float, taper: np.ndarray, inner: int = 3, outer: int = 12) -> np.ndarray:
    r"""Complex coherence of the views' residuals ``res`` (the line removed) near bin ``k0``,

    .. math:: \hat\rho_{vw} = \frac{\sum_k R_v(k) R_w(k)^*}{\sqrt{\sum_k |R_v(k)|^2 \sum_k |R_w(k)|^2}},

    over the tapered DFT's bins :math:`3 \le |k - k_0| \le 12` (a periodic frame's off-grid bins
    only): views of one loop (a position, its error, the controller output) carry the same noise
    there, which a weighting of each view by its own noise counts once per view."""
    R = np.fft.rfft(np.asarray(res, float) * taper, axis=1)
    k = np.arange(R.shape[1])
    near = (np.abs(k - k0) >= inner) & (np.abs(k - k0) <= outer) & (k >= 1)
    if frame.periodic:
        near &= ~frame.grid_mask[:R.shape[1]]
    C = R[:, near] @ R[:, near].conj().T
    d = np.sqrt(np.maximum(np.real(np.diag(C)), 1e-300))
    rho = C / np.outer(d, d)
    np.fill_diagonal(rho, 1.0)
    return rho


def _frequency_se(t: np.ndarray, D: np.ndarray, ab: np.ndarray, s: list, h: np.ndarray, f_hz: float,
                  project, rho: np.ndarray | None = None) -> float:
    r"""Sandwich standard error (Hz) of the frequency of a weighted least-squares fit of one
    sinusoid per view with a shared frequency (:func:`fit_line`; ``h`` the taper), the noise of
    view :math:`v` white at ``s[v]`` near the line and coherent between views as ``rho`` says
    (:func:`_coherence`; default none).

    With :math:`J_v` the derivatives of view :math:`v`'s fit (frequency, its two amplitudes),
    :math:`A = \sum_v J_v^\top H J_v / s_v^2` (the estimator's weights) and
    :math:`B_{vw} = \frac{1}{N}\sum_k c_k\,\mathrm{Re}\big[G_v(k)^H G_w(k)\,\rho_{vw}\big]`,
    :math:`G_v` the DFT of :math:`H J_v / s_v` and :math:`c_k` the one-sided spectrum's weights
    (Parseval: :math:`B_{vv} = J_v^\top H^2 J_v / s_v^2`), the variance is
    :math:`(A^{-1} B A^{-1})_{ff}`. ``D`` holds the projected regressors at ``f_hz``, and the
    frequency's column is the projection of the sinusoid's derivative,
    :math:`P\,[2\pi t(-a\sin\omega t + b\cos\omega t)]`: the projection does not commute with
    the factor :math:`t` (near a harmonic of the period it takes most of the sinusoid, and the
    derivative's projection is not :math:`t` times its own)."""
    nv = len(s)
    p = 1 + 2 * nv
    n = len(t)
    A = np.zeros((p, p))
    w = 2 * np.pi * f_hz * t
    c, sn = np.cos(w), np.sin(w)
    G = []
    for i in range(nv):
        a, b = ab[:, i]
        g = project(2 * np.pi * t * (-a * sn + b * c))       # d/d(frequency in Hz) of P(a cos + b sin)
        J = np.column_stack([g, D])
        idx = [0, 1 + 2 * i, 2 + 2 * i]
        A[np.ix_(idx, idx)] += J.T @ (J * h[:, None]) / s[i] ** 2
        G.append((idx, np.fft.rfft(J * (h / s[i])[:, None], axis=0)))
    wk = np.full(G[0][1].shape[0], 2.0)
    wk[0] = 1.0
    if n % 2 == 0:
        wk[-1] = 1.0
    rho = np.eye(nv) if rho is None else np.asarray(rho)
    B = np.zeros((p, p))
    for i, (ii, Gi) in enumerate(G):
        for j, (jj, Gj) in enumerate(G):
            B[np.ix_(ii, jj)] += np.real((Gi.conj() * wk[:, None]).T @ Gj * rho[i, j]) / n
    try:
        Ai = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        return float("inf")
    return float(math.sqrt(max((Ai @ B @ Ai)[0, 0], 0.0)))


def _leaks(frame: Frame, segs: dict, sigmas: dict, k: int, chi2_min: float = 30.0) -> bool:
    """Does a line found at grid bin ``k`` leak into its two off-grid neighbours? Then it is a
    line between grid frequencies that the nearest bin only caught (a rotor spinning at
    114.8 Hz under a 5 Hz grid peaks at 115 Hz), not one on the grid: an exact harmonic of the
    period puts all its power in its own bin. ``chi2_min`` is the neighbours' summed
    chi-square over their noise (two complex bins per view) that counts as leakage."""
    chi = 0.0
    for v, e in segs.items():
        X = np.fft.rfft(np.asarray(e, float))
        var = sigmas[v] ** 2 * frame.n if sigmas[v] > 0 else np.inf
        chi += float((abs(X[k - 1]) ** 2 + abs(X[min(k + 1, len(X) - 1)]) ** 2) / var)
    return chi > chi2_min * len(segs)


def _grid_line(frame: Frame, segs: dict, sigmas: dict, k: int) -> dict:
    r"""A line on the periodic grid: its DFT bin is its phasor (whole periods, no leakage), and
    nothing synchronous can be projected out of it. :math:`A_v = 2X_v(k)/n`."""
    t = frame.t_s
    w = 2 * np.pi * k * frame.df_hz * t
    out = {"f_hz": float(k * frame.df_hz), "phasor": {}, "se": {}, "chi2": {}, "component": {},
           "se_scale": math.sqrt(2.0 / frame.n), "on_grid": True}
    for v, e in segs.items():
        A = complex(2.0 * np.fft.rfft(np.asarray(e, float))[k] / frame.n)
        se = sigmas[v] * out["se_scale"]
        out["phasor"][v] = A
        out["se"][v] = se
        out["chi2"][v] = float(abs(A) ** 2 / se ** 2) if se > 0 else float("inf")
        out["component"][v] = A.real * np.cos(w) - A.imag * np.sin(w)
    out["f_se_hz"] = crb_frequency_se(frame.df_hz, max(out["chi2"].values(), default=0.0))
    return out


def crb_frequency_se(df_hz: float, chi2: float) -> float:
    r"""The Cramer-Rao bound of a sinusoid's frequency in white noise over a segment of resolution
    :math:`\Delta f`: :math:`\sigma_f = \frac{\sqrt{12}}{2\pi}\,\Delta f / \sqrt{\chi^2}`, with
    :math:`\chi^2 = |A|^2 / \sigma_A^2` the line's strength (:math:`\sigma_A` per real and
    imaginary part).

    Examples
    --------
    >>> round(crb_frequency_se(1.0, 12.0 / (2 * math.pi) ** 2), 12)     # chi2 = 12 / (2 pi)^2: one bin
    1.0
    """
    return float(math.sqrt(12.0) / (2 * math.pi) * df_hz / math.sqrt(max(chi2, 1e-300)))


def welch_transfer(s: np.ndarray, ys: dict, fs_hz: float, nperseg: int) -> dict:
    r"""Single-input transfer estimates :math:`\hat H = S_{sy}/S_{ss}` with their variance.

    .. math:: E|\hat H - H|^2 \approx \frac{S_{yy}(1-\gamma^2)}{K S_{ss}}
              = |\hat H|^2 \frac{1-\gamma^2}{K \gamma^2}

    (:math:`\gamma^2` the coherence, :math:`K` the effective number of averaged segments,
    Bendat & Piersol; half of it per real component). Returns ``f_hz``, ``Sss``, ``k_eff`` and
    per output ``H``, ``var``, ``coh``.
    """
    kw = dict(fs=fs_hz, nperseg=nperseg, noverlap=nperseg // 2, window="hann", detrend="constant")
    f, Sss = signal.welch(s, **kw)
    n_seg = max(1, (len(s) - nperseg) // (nperseg // 2) + 1)
    k_eff = max(1.0, n_seg / 1.06)       # Hann, 50 % overlap
    out = {"f_hz": f, "Sss": Sss, "k_eff": k_eff, "H": {}, "var": {}, "coh": {}}
    for c, y in ys.items():
        _, Ssy = signal.csd(s, y, **kw)
        _, Syy = signal.welch(y, **kw)
        with np.errstate(divide="ignore", invalid="ignore"):
            H = Ssy / Sss
            coh = np.clip(np.nan_to_num(np.abs(Ssy) ** 2 / (Sss * Syy), nan=0.0), 0.0, 1.0)
            var = np.nan_to_num(Syy * (1 - coh) / (k_eff * Sss), nan=0.0, posinf=0.0)
        out["H"][c] = H
        out["var"][c] = var
        out["coh"][c] = coh
    return out
