r"""Robustness: μ over frequency, frequency responses, classical margins of conditionally stable
loops and the ISO 14839-3 sensitivity zones; and their application to the AMB
(:func:`mu_for_case`, :func:`sensitivity_baseline`).

The generic functions take a callable ``f(hz) -> complex matrix`` or an array of frequency
responses; the generalized plant (Fig. 6) is :mod:`ssamb.generalized_plant`.

μ-analysis (paper, section 4).  With :math:`N` the closed-loop interconnection (3) and
:math:`N_{11}` the map from the uncertainty outputs :math:`u_\Delta` to its inputs
:math:`y_\Delta`, the loop is robustly stable for all :math:`\lVert\Delta\rVert_\infty \le 1`
iff :math:`\sup_\omega \mu_{\boldsymbol\Delta}(N_{11}(j\omega)) < 1`.

Margins reported by :class:`MuSweep` (``peak`` = :math:`\sup_\omega \bar\mu`, the upper bound):

* ``margin = 1 / peak``: the *multiplicative* robust stability margin — stability is
  guaranteed for every :math:`\Delta` with :math:`\lVert\Delta\rVert_\infty < 1/\text{peak}`.
* ``margin_difference = 1 - peak``: the paper's phrasing ("the difference between one and
  the peak value reflects the stability margin"); positive means robustly stable.
* ``scale_for_unity = 1 / peak``: the factor by which the uncertainty weight must be
  multiplied to bring the μ peak to exactly 1.  For an additive (or any LFT) uncertainty
  :math:`W\Delta`, :math:`N_{11}` is linear in :math:`W` (:math:`N_{11} = W\,T` with
  :math:`T` independent of :math:`W`) and μ is positively homogeneous,
  :math:`\mu(kN_{11}) = |k|\,\mu(N_{11})`, so scaling :math:`W` by :math:`k` scales the μ
  curve by :math:`k` and ``scale_for_unity`` is ``1/peak``.  (The paper scaled its weight by
  0.0012 "to obtain useful results".)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import control

import numpy as np

from .mu import MuResult, mussv

__all__ = [
    "MuSweep",
    "mu_frequency_response",
    "frequency_response_matrix",
    "ISO14839_LIMITS",
    "iso14839_zone",
    "SensitivityPeak",
    "sensitivity_peak",
    "loop_margins",
    "log_grid",
    "mu_for_case",
    "sensitivity_baseline",
]

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


# ---------------------------------------------------------------------------- peak search
def _golden_max(fun: Callable[[float], float], a: float, b: float, *, log: bool,
                xtol: float = 1e-7, maxiter: int = 60) -> tuple[float, float]:
    """Golden-section search for a maximum of ``fun`` on ``[a, b]`` (in log-frequency when
    ``log``); returns ``(x, fun(x))`` of the best point evaluated."""
    ta, tb = (np.log(a), np.log(b)) if log else (a, b)
    tr = (lambda t: float(np.exp(t))) if log else (lambda t: float(t))
    best = (tr(ta), fun(tr(ta)))
    vb = fun(tr(tb))
    if vb > best[1]:
        best = (tr(tb), vb)
    c = tb - _GOLDEN * (tb - ta)
    d = ta + _GOLDEN * (tb - ta)
    fc, fd = fun(tr(c)), fun(tr(d))
    for _ in range(maxiter):
        if abs(tb - ta) <= xtol * max(1.0, abs(ta) if not log else 1.0):
            break
        if fc >= fd:
            tb, d, fd = d, c, fc
            c = tb - _GOLDEN * (tb - ta)
            fc = fun(tr(c))
        else:
            ta, c, fc = c, d, fd
            d = ta + _GOLDEN * (tb - ta)
            fd = fun(tr(d))
    for t, v in ((c, fc), (d, fd)):
        if v > best[1]:
            best = (tr(t), v)
    return best


def _local_maxima(y: np.ndarray, k: int) -> list[int]:
    """Indices of up to ``k`` largest local maxima of ``y`` (end points included)."""
    n = len(y)
    idx = [i for i in range(n)
           if (i == 0 or y[i] >= y[i - 1]) and (i == n - 1 or y[i] >= y[i + 1])]
    idx.sort(key=lambda i: -y[i])
    return idx[:k]


# ---------------------------------------------------------------------------- μ sweep
@dataclass(frozen=True)
class MuSweep:
    """μ bounds over frequency.

    Attributes
    ----------
    freqs_hz, upper, lower : ndarray
        Frequency grid (sorted; includes the refinement points) and the bounds on it.
    peak, peak_hz : float
        :math:`\\max_f \\bar\\mu(f)` (upper bound) and where it occurs.
    peak_lower : float
        The lower bound at ``peak_hz`` (``peak_lower <= mu_peak <= peak``).
    margin : float
        ``1 / peak``: robust stability for all ``||Δ||∞ < margin`` (inf when peak = 0).
    margin_difference : float
        ``1 - peak``: the paper's "difference between one and the peak value".
    scale_for_unity : float
        Factor by which the uncertainty weight must be multiplied to bring the peak to 1
        (``1 / peak``, by the linearity of μ in the weight).
    """

    freqs_hz: np.ndarray
    upper: np.ndarray
    lower: np.ndarray
    peak: float
    peak_hz: float
    peak_lower: float
    margin: float
    margin_difference: float
    scale_for_unity: float

    def as_dict(self) -> dict:
        """The summary used in ``results/summary.json`` (``mu.{case}``)."""
        return {"peak": self.peak, "peak_hz": self.peak_hz, "margin": self.margin,
                "margin_difference": self.margin_difference,
                "scale_for_unity": self.scale_for_unity, "peak_lower": self.peak_lower}


def mu_frequency_response(
    N11: Callable[[float], np.ndarray] | np.ndarray,
    freqs_hz,
    blk,
    refine: bool = True,
    *,
    n_peaks: int = 3,
    xtol: float = 1e-7,
    **mussv_kwargs,
) -> MuSweep:
    """μ upper and lower bounds of :math:`N_{11}(j2\\pi f)` over a frequency grid.

    Parameters
    ----------
    N11 : callable, control LTI system or ndarray
        Either ``f(hz) -> (p, q)`` complex matrix, a ``control`` LTI system (evaluated with
        :func:`frequency_response_matrix`), or an array ``(n_freq, p, q)`` (or ``(n_freq,)``
        for a SISO response) evaluated at ``freqs_hz``.
    freqs_hz : array_like
        Frequencies in Hz (non-negative, strictly increasing after sorting).
    blk : block structure
        As for :func:`ssamb.mu.mussv` (``M`` is ``(sum c) × (sum r)``).
    refine : bool
        With a callable ``N11``, refine around the ``n_peaks`` largest local maxima of the
        upper bound: a dense local grid over the neighbouring grid interval followed by a
        golden-section search (in log-frequency for positive frequencies) down to a relative
        frequency tolerance ``xtol``.  Ignored for array input.
    **mussv_kwargs
        Passed to :func:`ssamb.mu.mussv` (e.g. ``seed``).

    Returns
    -------
    MuSweep
    """
    freqs = np.asarray(freqs_hz, dtype=float).ravel()
    if freqs.size == 0:
        raise ValueError("freqs_hz is empty")
    if not np.all(np.isfinite(freqs)) or np.any(freqs < 0):
        raise ValueError("freqs_hz must be finite and non-negative")
    order = np.argsort(freqs, kind="stable")
    freqs = freqs[order]
    if np.any(np.diff(freqs) == 0):
        raise ValueError("freqs_hz has repeated frequencies")

    cache: dict[float, MuResult] = {}

    if hasattr(N11, "ninputs"):  # a control LTI system (its __call__ takes s, not hz)
        sys = N11

        def N11(f):  # noqa: N802
            return frequency_response_matrix(sys, [f])[0]

    if callable(N11):
        fun = N11

        def mu_at(f: float) -> MuResult:
            f = float(f)
            if f not in cache:
                cache[f] = mussv(_as_matrix(fun(f)), blk, **mussv_kwargs)
            return cache[f]
    else:
        arr = np.asarray(N11)
        if arr.ndim == 1:
            arr = arr.reshape(-1, 1, 1)
        if arr.ndim != 3 or arr.shape[0] != len(order):
            raise ValueError(
                f"N11 array must be (n_freq, p, q) with n_freq = {len(order)}, got {arr.shape}")
        arr = arr[order]
        for f, M in zip(freqs, arr):
            cache[float(f)] = mussv(M, blk, **mussv_kwargs)
        mu_at = cache.__getitem__

    up = np.array([mu_at(f).upper for f in freqs])
    if refine and callable(N11) and len(freqs) >= 2:
        for i in _local_maxima(up, n_peaks):
            lo = freqs[max(i - 1, 0)]
            hi = freqs[min(i + 1, len(freqs) - 1)]
            use_log = lo > 0
            local = np.geomspace(lo, hi, 9) if use_log else np.linspace(lo, hi, 9)
            vals = np.array([mu_at(f).upper for f in local])
            j = int(np.argmax(vals))
            a, b = local[max(j - 1, 0)], local[min(j + 1, len(local) - 1)]
            if b > a:
                _golden_max(lambda f: mu_at(f).upper, a, b, log=use_log, xtol=xtol)
    fs = np.array(sorted(cache))
    res = [cache[f] for f in fs]
    upper = np.array([r.upper for r in res])
    lower = np.array([r.lower for r in res])
    k = int(np.argmax(upper))
    peak = float(upper[k])
    inv = 1.0 / peak if peak > 0 else np.inf
    return MuSweep(freqs_hz=fs, upper=upper, lower=lower, peak=peak, peak_hz=float(fs[k]),
                   peak_lower=float(lower[k]), margin=inv, margin_difference=1.0 - peak,
                   scale_for_unity=inv)


def _as_matrix(x) -> np.ndarray:
    x = np.asarray(x, dtype=complex)
    return x.reshape(1, 1) if x.ndim == 0 else x


# ----------------------------------------------------------------- frequency responses
def frequency_response_matrix(sys, freqs_hz) -> np.ndarray:
    """Complex frequency response ``(n_freq, p, q)`` of a ``control`` LTI system.

    Uses ``control.frequency_response`` (``s = j 2π f`` for continuous systems,
    ``z = exp(j 2π f dt)`` for discrete ones; frequencies above Nyquist of a discrete system
    are evaluated on the unit circle all the same, with control's warning).
    """
    import control

    freqs = np.asarray(freqs_hz, dtype=float).ravel()
    if not np.all(np.isfinite(freqs)) or np.any(freqs < 0):
        raise ValueError("freqs_hz must be finite and non-negative")
    resp = control.frequency_response(sys, 2.0 * np.pi * freqs, squeeze=False)
    fr = np.asarray(resp.frdata if hasattr(resp, "frdata") else resp.fresp)  # (p, q, nfreq)
    return np.ascontiguousarray(np.moveaxis(fr, -1, 0))


# ------------------------------------------------------------------------- ISO 14839-3
#: Zone boundaries of the peak sensitivity magnitude (ISO 14839-3, as widely quoted:
#: A/B at 3 (9.5 dB), B/C at 4 (12 dB), C/D at 5 (14 dB)).  A value on a boundary belongs to
#: the worse zone.
ISO14839_LIMITS = {"A": 3.0, "B": 4.0, "C": 5.0}


def iso14839_zone(peak_sensitivity: float) -> str:
    """ISO 14839-3 stability-margin zone from the peak sensitivity magnitude (absolute, not dB).

    ``A`` (< 3, newly commissioned machines), ``B`` (3 … < 4, unrestricted long-term operation),
    ``C`` (4 … < 5, limited period), ``D`` (>= 5, damage may occur).
    """
    s = float(peak_sensitivity)
    if not np.isfinite(s) or s < 0:
        raise ValueError(f"peak sensitivity must be finite and >= 0, got {peak_sensitivity}")
    for zone, limit in ISO14839_LIMITS.items():
        if s < limit:
            return zone
    return "D"


@dataclass(frozen=True)
class SensitivityPeak:
    """Peak of the sensitivity magnitude (σ̄ for MIMO) and its ISO 14839-3 zone."""

    peak: float
    peak_db: float
    peak_hz: float
    zone: str


def _sens_value(H: np.ndarray, kind: str) -> float:
    H = _as_matrix(H)
    if kind == "L":
        n = H.shape[0]
        if H.shape[1] != n:
            raise ValueError("a loop transfer L must be square")
        H = np.linalg.inv(np.eye(n) + H)
    return float(np.linalg.norm(H, 2))


def sensitivity_peak(sys_or_response, freqs_hz, kind: str = "S", refine: bool = True,
                     xtol: float = 1e-7) -> SensitivityPeak:
    """Peak sensitivity :math:`\\max_f \\bar\\sigma(S(j2\\pi f))` over a grid.

    Parameters
    ----------
    sys_or_response : control LTI system, callable ``f(hz) -> matrix``, or ndarray
        The sensitivity ``S`` (``kind="S"``) or the loop transfer ``L`` (``kind="L"``,
        then :math:`S = (I + L)^{-1}`, negative feedback).  An array is ``(n_freq, p, q)`` or
        ``(n_freq,)``.
    freqs_hz : array_like
        Frequency grid in Hz.
    refine : bool
        Golden-section refinement around the grid maximum (LTI system or callable only).
    """
    if kind not in ("S", "L"):
        raise ValueError("kind must be 'S' or 'L'")
    freqs = np.sort(np.asarray(freqs_hz, dtype=float).ravel())
    if freqs.size == 0 or not np.all(np.isfinite(freqs)) or np.any(freqs < 0):
        raise ValueError("freqs_hz must be a non-empty set of finite, non-negative frequencies")
    fun = None
    if callable(sys_or_response) and not hasattr(sys_or_response, "nstates") \
            and not hasattr(sys_or_response, "ninputs"):
        fun = sys_or_response
    elif hasattr(sys_or_response, "ninputs"):
        sys = sys_or_response

        def fun(f):  # noqa: F811 - evaluated one frequency at a time during refinement
            return frequency_response_matrix(sys, [f])[0]
    if fun is not None:
        if hasattr(sys_or_response, "ninputs"):
            resp = frequency_response_matrix(sys_or_response, freqs)
        else:
            resp = np.array([_as_matrix(fun(f)) for f in freqs])
    else:
        resp = np.asarray(sys_or_response)
        if resp.ndim == 1:
            resp = resp.reshape(-1, 1, 1)
        if resp.shape[0] != freqs.size:
            raise ValueError("response array and freqs_hz have different lengths")
    vals = np.array([_sens_value(H, kind) for H in resp])
    k = int(np.argmax(vals))
    best_f, best_v = float(freqs[k]), float(vals[k])
    if refine and fun is not None and freqs.size >= 2:
        lo, hi = freqs[max(k - 1, 0)], freqs[min(k + 1, freqs.size - 1)]
        f, v = _golden_max(lambda f: _sens_value(fun(f), kind), lo, hi, log=lo > 0, xtol=xtol)
        if v > best_v:
            best_f, best_v = f, v
    return SensitivityPeak(peak=best_v, peak_db=float(20 * np.log10(best_v)) if best_v > 0
                           else -np.inf, peak_hz=best_f, zone=iso14839_zone(best_v))


# ---------------------------------------------------------------------- classical margins
def loop_margins(L: control.LTI, freqs_hz: np.ndarray) -> dict:
    r"""Classical margins of a SISO loop that may be open-loop unstable (conditionally stable).

    On a dense grid: every gain crossover (:math:`|L| = 1`) gives a phase margin
    :math:`180° + \angle L` (wrapped), and every phase crossover (:math:`\angle L = \pm 180°`,
    i.e. L real negative) gives a gain factor :math:`1/|L|`. For an open-loop unstable plant
    the loop has an *upper* gain margin (factor > 1 before instability) and a *lower* one
    (reduction factor < 1): both are reported, with the smallest phase margin. (A margin
    computed for a stable open loop, such as ``control.stability_margins``, does not apply.)
    """
    f = np.asarray(freqs_hz, float)
    w = 2 * np.pi * f
    arg = np.exp(1j * w * L.dt) if L.dt else 1j * w
    Lw = np.asarray(L(arg)).reshape(-1)
    mag = np.abs(Lw)
    ph = np.degrees(np.angle(Lw))
    pm, f_pm = [], []
    for i in np.flatnonzero(np.diff(np.sign(mag - 1.0)) != 0):
        a = (1.0 - mag[i]) / (mag[i + 1] - mag[i])
        p = ph[i] + a * (((ph[i + 1] - ph[i]) + 180) % 360 - 180)
        pm.append(((180.0 + p) + 180) % 360 - 180)
        f_pm.append(f[i] + a * (f[i + 1] - f[i]))
    up, low, f_up, f_low = [], [], [], []
    im = Lw.imag
    for i in np.flatnonzero(np.diff(np.sign(im)) != 0):
        a = im[i] / (im[i] - im[i + 1])
        re = Lw.real[i] + a * (Lw.real[i + 1] - Lw.real[i])
        if re >= 0:
            continue
        k = 1.0 / abs(re)
        fc = f[i] + a * (f[i + 1] - f[i])
        (up if k > 1 else low).append(k)
        (f_up if k > 1 else f_low).append(fc)
    res = {"phase_margin_deg": None, "phase_margin_hz": None, "gain_margin_upper_db": None,
           "gain_margin_upper_hz": None, "gain_margin_lower_db": None, "gain_margin_lower_hz": None,
           "gain_crossovers_hz": [float(x) for x in f_pm]}
    if pm:
        j = int(np.argmin(np.abs(pm)))
        res["phase_margin_deg"], res["phase_margin_hz"] = float(abs(pm[j])), float(f_pm[j])
    if up:
        j = int(np.argmin(up))
        res["gain_margin_upper_db"], res["gain_margin_upper_hz"] = float(20 * np.log10(up[j])), float(f_up[j])
    if low:
        j = int(np.argmax(low))
        res["gain_margin_lower_db"], res["gain_margin_lower_hz"] = float(20 * np.log10(low[j])), float(f_low[j])
    return res



# ---------------------------------------------------------------------- the AMB analyses
def log_grid(f_min_hz: float, f_max_hz: float, n_points: int) -> np.ndarray:
    """The analysis frequency grid: ``n_points`` log-spaced frequencies (Hz)."""
    return np.logspace(np.log10(float(f_min_hz)), np.log10(float(f_max_hz)), int(n_points))


def mu_for_case(loop, weights: Mapping, case: str, freqs_hz, refine: bool = True) -> MuSweep:
    """μ over frequency of the generalized plant (Fig. 6) for one uncertainty case (Fig. 8):
    :math:`N_{11}` of :func:`ssamb.generalized_plant.n11_function` with the case's block
    structure; ``loop`` is :func:`ssamb.generalized_plant.uncertainty_loop`."""
    from .closed_loop import stability
    from .generalized_plant import case_structure, n11_function

    rep = stability(loop)
    if not rep.stable:
        raise ValueError(f"the nominal closed loop is unstable ({rep}): mu measures robust stability only "
                         "about a stable nominal loop")
    return mu_frequency_response(n11_function(loop, weights, case), freqs_hz, case_structure(case), refine=refine)


def sensitivity_baseline(plant, amplifier, selfsensing, pid, freqs_hz) -> dict:
    """ISO 14839-3 peak sensitivity and the classical margins of each axis (the baseline the
    paper argues against). The sensitivity of an axis is measured where its feedback signal
    enters the controller (x: ``x_meas``, y: ``y_ss``), the other axis closed:
    :math:`S = 1/(1 + L)` of :func:`ssamb.closed_loop.loop_transfer`."""
    from .closed_loop import loop_transfer

    out = {}
    for axis in ("x", "y"):
        L = loop_transfer(plant, amplifier, selfsensing, pid, pid, axis)
        sp = sensitivity_peak(L, freqs_hz, kind="L")
        mg = loop_margins(L, np.logspace(-1, np.log10(0.45 / float(L.dt)), 20000))
        out[axis] = {"peak_sensitivity": float(sp.peak), "peak_sensitivity_db": float(sp.peak_db),
                     "peak_hz": float(sp.peak_hz), "iso14839_zone": sp.zone, **mg}
    return out
