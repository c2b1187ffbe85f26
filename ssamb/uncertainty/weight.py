r"""The uncertainty weight W(s): a stable, minimum-phase, strictly proper fit within ``tol_db``
of the envelope and above the ETFE on every line (paper section 5, Fig. 7)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import numpy as np
import scipy.optimize
import scipy.sparse

from .envelope import _DB, Envelope, _check_freq_mag, _to_db

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

        def split(v):
            return v[0], v[1:1 + nz], v[1 + nz:1 + nz + npol]

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
       it does not violate the 3 dB band inside the measured range"; this keeps :math:`|W|` sane on the
       wide grid of the mu analysis). Out of band :math:`|W|` follows the extension only as closely as a
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
    f, m = _check_freq_mag(freqs_hz, etfe_mag, "etfe_mag")
    tol_db = float(tol_db)
    if not (tol_db > 0 and math.isfinite(tol_db)):
        raise ValueError(f"tol_db must be > 0, got {tol_db!r}")
    if int(max_order) != max_order or max_order < 1:
        raise ValueError(f"max_order must be an integer >= 1, got {max_order!r}")
    if isinstance(envelope_mag, Envelope):
        env = envelope_mag
        if f_rolloff_hz is not None:
            raise ValueError("f_rolloff_hz is taken from the Envelope; do not pass it as well")
    else:
        env = Envelope.from_samples(f, envelope_mag, f_rolloff_hz=f_rolloff_hz)
    search = _WeightSearch(f, m, env, tol_db, int(max_order))
    best = search.run(polish_out_of_band)
    return _weight_fit(best, search, env)


class _Candidate(NamedTuple):
    """One weight tried: its order (poles), in-band deviation (dB), gain (dB), log10 corner
    frequencies of zeros and poles, gain raised for eq. (6) (dB) and the smallest margin."""

    order: int
    dev: float
    gain_db: float
    xz: np.ndarray
    xp: np.ndarray
    raise_db: float
    margin: float


class _WeightSearch:
    """The steps of :func:`fit_weight` over fixed grids: asymptotes, refinement, pruning,
    growing, out-of-band polish. Every candidate tried is recorded in ``history``."""

    def __init__(self, f: np.ndarray, m: np.ndarray, env: Envelope, tol_db: float, max_order: int):
        self.tol_db, self.max_order = tol_db, max_order
        self.band_hz = (float(f[0]), float(f[-1]))
        self.cap = max_order + 6  # intermediate candidates may be richer; they are pruned to max_order
        x_lo, x_hi = math.log10(float(f[0])), math.log10(float(f[-1]))
        self.x_roll = math.log10(env.f_rolloff_hz)
        self.yl, self.xl = _to_db(m), np.log10(f)
        # grids: band for the final check (dense + lines), band for the optimiser (coarser: the
        # envelope and |W| are smooth on a 0.02-decade scale), extension (below and above the band)
        n_band = max(50, int(math.ceil((x_hi - x_lo) * 200)))
        self.xb_all = np.unique(np.concatenate([np.linspace(x_lo, x_hi, n_band), self.xl]))
        self.eb_all = env.db(10.0 ** self.xb_all)
        self.xb_opt = np.linspace(x_lo, x_hi, max(20, int(math.ceil((x_hi - x_lo) * 30))))
        self.eb_opt = env.db(10.0 ** self.xb_opt)
        xo = np.concatenate([np.linspace(x_lo - 1.0, x_lo, 60, endpoint=False),
                             np.linspace(x_hi, self.x_roll + 1.0, max(60, int((self.x_roll + 1 - x_hi) * 60)))[1:]])
        self.x_track = np.arange(x_lo - 1.0, self.x_roll + 1.0 + 1e-12, 0.005)
        self.e_track = env.db(10.0 ** self.x_track)
        # only lines that come within tol of the envelope can be violated while |W - E| <= tol;
        # the others are checked after each solve (and the gain raised if one is not bounded)
        near = (env.db(f) - self.yl) <= 1.2 * tol_db
        self.prob = _Problem(self.xb_opt, self.eb_opt, xo, env.db(10.0 ** xo), self.xl[near], self.yl[near],
                             tol_db, 0.02, x_lo - 2.0, self.x_roll + 2.0)
        # W >= data on the lines, so no weight beats max(data - envelope): if that exceeds tol_db
        # (an envelope passed in below the ETFE), one candidate is enough
        self.hopeless = float(np.max(self.yl - env.db(f))) > tol_db
        self.history: list[dict] = []

    def candidate(self, g, xz, xp, how: str) -> _Candidate | None:
        """Refine (SLSQP) and finish (eq. (6) gain raise) a set of corners; None if too rich."""
        xz, xp = np.sort(np.asarray(xz, float)), np.sort(np.asarray(xp, float))
        while xp.size < xz.size + 1:
            xp = np.append(xp, self.x_roll)
        if xp.size > self.cap:
            return None
        g, xz, xp = self.prob.solve(g, xz, xp)
        g2, raise_db, dev, margin = _finish(g, xz, xp, self.xb_all, self.eb_all, self.xl, self.yl)
        self.history.append({"how": how, "order": int(xp.size), "n_zeros": int(xz.size),
                             "max_dev_db": dev, "gain_raise_db": raise_db})
        return _Candidate(int(xp.size), dev, g2, np.sort(xz), np.sort(xp), raise_db, margin)

    def ok(self, c: _Candidate | None) -> bool:
        return c is not None and c.dev <= self.tol_db and c.order <= self.max_order

    def removals(self, c: _Candidate) -> list:
        """Cheapest removals first: drop a zero with its nearest pole (or a surplus pole), keep
        the rest, re-centre the gain, rank by the resulting deviation (no re-optimisation)."""
        pairs = {(i, int(np.argmin(np.abs(c.xp - c.xz[i])))) for i in range(c.xz.size)}
        if c.xp.size > c.xz.size + 1:
            pairs |= {(None, j) for j in range(c.xp.size)}
        opts = []
        for i, j in pairs:
            z2 = c.xz if i is None else np.delete(c.xz, i)
            p2 = np.delete(c.xp, j)
            d = weight_db(10.0 ** self.xb_opt, c.gain_db, 10.0 ** z2, 10.0 ** p2) - self.eb_opt
            opts.append((0.5 * (d.max() - d.min()), c.gain_db - 0.5 * (d.max() + d.min()), z2, p2))
        opts.sort(key=lambda o: o[0])
        return opts

    def prune(self, c: _Candidate, force_to: int | None) -> _Candidate:
        """Remove corners a pair at a time (three cheapest removals tried, re-optimised): forced
        while the order exceeds ``force_to``, then further while the fit stays within tol_db."""
        while c.xz.size >= 1 or c.xp.size > c.xz.size + 1:
            forced = force_to is not None and c.order > force_to
            t_best = None
            for _, g2, z2, p2 in self.removals(c)[:3]:
                t = self.candidate(g2, z2, p2, "pruned")
                if t is not None and (t_best is None or t.dev < t_best.dev):
                    t_best = t
                if t_best is not None and t_best.dev <= self.tol_db:
                    break  # good enough: do not try the other removals
            if t_best is None or not (forced or t_best.dev <= self.tol_db):
                break
            c = t_best
        return c

    def from_asymptotes(self, candidates: list) -> _Candidate | None:
        """Steps 1-3: asymptotic corners with ``delta`` = tol, tol/2, ... refined; the first
        within tol is pruned to ``max_order`` and the lowest order within tol."""
        delta = self.tol_db
        for _ in range(1 if self.hopeless else 4):
            g0, z0, p0 = _asymptotic_corners(self.x_track, self.e_track, delta)
            c = self.candidate(g0, z0, p0, f"asymptotes delta={delta:.3g} dB")
            delta /= 2.0
            if c is None:
                return None
            candidates.append(c)
            if c.dev <= self.tol_db:
                c = self.prune(c, self.max_order)
                candidates.append(c)
                if self.ok(c):
                    return c
        return None

    def _admissible(self, candidates: list) -> list:
        admissible = [c for c in candidates if c.order <= self.max_order]
        if not admissible:
            c = self.candidate(float(np.max(self.eb_all)), np.array([]), np.array([self.x_roll]), "constant")
            admissible = [c]
            candidates.append(c)
        return admissible

    def grow(self, candidates: list) -> _Candidate | None:
        """Greedy: from the best admissible candidate, add a zero/pole pair around the worst
        in-band deviation, re-optimise, repeat up to ``max_order``."""
        cur = min(self._admissible(candidates), key=lambda c: c.dev)
        for _ in range(self.max_order):
            if cur.order + 1 > self.max_order:
                break
            d = weight_db(10.0 ** self.xb_all, cur.gain_db, 10.0 ** cur.xz, 10.0 ** cur.xp) - self.eb_all
            k = int(np.argmax(np.abs(d)))
            xs, sgn = self.xb_all[k], (1.0 if d[k] < 0 else -1.0)  # too low: a local rise, zero then pole
            c = self.candidate(cur.gain_db, np.append(cur.xz, xs - 0.15 * sgn), np.append(cur.xp, xs + 0.15 * sgn),
                               "added corner pair")
            if c is None:
                break
            candidates.append(c)
            cur = c  # keep growing from the last candidate (the best is kept in `candidates`)
            if self.ok(c):
                return self.prune(c, None)
        return None

    def polish(self, best: _Candidate) -> _Candidate:
        """Step 4: with the in-band deviation held below a third of the way from what was reached
        to tol_db, bring |W| as close as possible to the extension out of band."""
        limit = best.dev + (self.tol_db - best.dev) / 3.0
        g2, z2, p2 = self.prob.solve(best.gain_db, best.xz, best.xp, band_limit=limit)
        g2, raise_db, dev, margin = _finish(g2, z2, p2, self.xb_all, self.eb_all, self.xl, self.yl)
        self.history.append({"how": "out-of-band polish", "order": int(p2.size), "n_zeros": int(z2.size),
                             "max_dev_db": dev, "gain_raise_db": raise_db})
        if dev <= self.tol_db:
            return _Candidate(int(p2.size), dev, g2, np.sort(z2), np.sort(p2), raise_db, margin)
        return best

    def run(self, polish_out_of_band: bool) -> _Candidate:
        candidates: list[_Candidate] = []
        best = self.from_asymptotes(candidates)
        if best is None and not self.hopeless:
            best = self.grow(candidates)
        if best is None:
            return min(self._admissible(candidates), key=lambda c: c.dev)
        return self.polish(best) if polish_out_of_band else best


def _weight_fit(best: _Candidate, search: _WeightSearch, env: Envelope) -> WeightFit:
    """The :class:`WeightFit` of the selected candidate (transfer function and cascade)."""
    import control

    zeros_hz, poles_hz = 10.0 ** best.xz, 10.0 ** best.xp
    k_dc = 10.0 ** (best.gain_db / _DB)
    wz, wp = 2.0 * np.pi * zeros_hz, 2.0 * np.pi * poles_hz
    W = control.zpk(-wz, -wp, k_dc * np.prod(wp) / np.prod(wz) if wz.size else k_dc * np.prod(wp))
    return WeightFit(
        W=W, W_ss=_cascade_ss(k_dc, wz, wp), gain=k_dc, zeros_hz=zeros_hz, poles_hz=poles_hz,
        order=int(best.order), max_dev_db=float(best.dev), within_tol=bool(best.dev <= search.tol_db),
        bound_holds=bool(best.margin >= 0.0), min_margin_db=float(best.margin),
        gain_raise_db=float(best.raise_db), tol_db=search.tol_db,
        band_hz=search.band_hz,
        envelope=env, history=search.history,
    )
