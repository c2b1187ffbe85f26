r"""Fit an effect's parameters by simulation, and score the fit on the held-out part.

Cost (fitting part, views :math:`v` whitened by their noise floors :math:`\sigma_v`):

.. math:: J(\theta) = \sum_v \sum_{t \in \mathrm{fit}} \left(\frac{y_v(t) - \hat y_v(t;\theta)}{\sigma_v}\right)^2 .

:func:`fit_effect` minimises it by Levenberg-Marquardt on the simulator: a forward-difference
Jacobian (one simulation of the fitting part per parameter), then steps
:math:`(J^T J + \lambda\,\mathrm{diag}\,J^T J)\Delta = J^T r`, each costing one simulation,
with Broyden rank-one updates of the Jacobian. The covariance of the estimate is
:math:`\hat s^2 (J^T J)^{-1}` with :math:`\hat s^2 = J(\hat\theta)/(n - p)` (standard errors grow
with the misfit).

:func:`holdout_score` compares the held-out residual of a base model and a candidate. With
:math:`r_0` and :math:`r_1` the whitened held-out residuals and :math:`\delta = r_0 - r_1` the
change of the model,

.. math:: z = \frac{\|r_0\|^2 - \|r_1\|^2}{2\|\delta\|}

is standard normal with mean :math:`-\|\delta\|/2` when the base model is right (the residual
is noise), and large when the candidate explains what the base model missed: a one-sided test.
The BIC change on the fitting part, :math:`n \ln(J_1/J_0) + p \ln n`, is the penalty for
parameters; ``explained`` is the fraction of each view's residual excess over its noise
(:math:`\overline{r^2} - 1`) that the candidate removes, averaged over the views that stood
clearly above the noise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .data import VIEWS, views
from .models import EffectModel

__all__ = ["FitResult", "whitened", "fit_effect", "holdout_score"]


def whitened(meas_v: dict, model_v: dict, sl: slice, sigma: dict) -> np.ndarray:
    """Stacked residual of all views over ``sl``, each divided by its noise level."""
    return np.concatenate([(meas_v[v][sl] - model_v[v][sl]) / sigma[v] for v in VIEWS])


@dataclass
class FitResult:
    """A fitted effect.

    Attributes
    ----------
    model : EffectModel
    theta, se : numpy.ndarray
        Estimate and standard error (SI units of ``model.params``).
    identifiable : numpy.ndarray of bool
        Parameters the data are sensitive to (the others stay at their start value).
    cost0, cost : float
        Fitting-part cost of the base model and of the fit.
    n : int
        Whitened samples in the cost.
    sims : int
        Simulations used.
    effects : list
        Effect specs at the estimate.
    """

    model: EffectModel
    theta: np.ndarray
    se: np.ndarray
    identifiable: np.ndarray
    cost0: float
    cost: float
    n: int
    sims: int
    iterations: int
    effects: list = field(default_factory=list)

    @property
    def delta_bic(self) -> float:
        p = int(np.count_nonzero(self.identifiable))
        return float(self.n * math.log(max(self.cost, 1e-300) / max(self.cost0, 1e-300)) + p * math.log(self.n))


def _scan(replay, base_effects, model, meas_v, fit_sl, sigma, u, lo, hi, scan_s):
    """Coordinate-wise global scan of the parameters that have a grid (a coarse pass over
    every 5th point, a fine pass around the best), each followed by a bounded scalar
    refinement between the grid neighbours of its best point; the cost is taken over the
    first ``scan_s`` seconds of the fitting part.  Returns (u, cost on the
    scan window, simulations)."""
    from scipy.optimize import minimize_scalar

    n_end = min(fit_sl.stop, fit_sl.start + max(int(scan_s * replay.record.fs_hz), 1))
    sl = slice(fit_sl.start, n_end)
    sims = 0

    def cost(uu):
        nonlocal sims
        th = np.clip(model.theta0 + uu * model.step, model.lower, model.upper)
        sims += 1
        rr = whitened(meas_v, views(replay.run(base_effects + model.build(th), n=n_end)), sl, sigma)
        return float(rr @ rr)

    u = u.copy()
    best = cost(u)
    for i, g in enumerate(model.grid):
        if g is None:
            continue
        ug = np.clip((np.asarray(g, float) - model.theta0[i]) / model.step[i], lo[i], hi[i])
        cs = np.full(len(ug), np.inf)

        def at(j, i=i, ug=ug, cs=cs):
            if not np.isfinite(cs[j]):
                uu = u.copy()
                uu[i] = ug[j]
                cs[j] = cost(uu)
            return cs[j]
        # coarse pass (every 5th point); when nothing on it beats the local fit, the local
        # fit is kept (a smooth cost: its minimum is global); else a fine pass around the best
        coarse = list(range(0, len(ug), 5))
        for j in coarse:
            at(j)
        k = int(np.nanargmin(cs))
        if not cs[k] < best:
            continue
        for j in range(max(k - 5, 0), min(k + 6, len(ug))):
            at(j)
        k = int(np.argmin(cs))
        best, u[i] = cs[k], ug[k]
        a, b = ug[max(k - 1, 0)], ug[min(k + 1, len(ug) - 1)]
        if b > a:
            def f(x, i=i):
                nonlocal best
                uu = u.copy()
                uu[i] = x
                c = cost(uu)
                if c < best:
                    best, u[i] = c, x
                return c
            minimize_scalar(f, bounds=(a, b), method="bounded",
                            options={"xatol": 1e-4 * (b - a), "maxiter": 30})
    return u, best, sims


def fit_effect(replay, base_effects: list, model: EffectModel, meas_v: dict, base_v: dict, fit_sl: slice,
               sigma: dict, max_iter: int = 6, scan_above: float = 2.0, scan_s: float = 0.5) -> FitResult:
    """Fit ``model`` added to ``base_effects`` on the fitting part (see module docstring).

    Parameters
    ----------
    replay : Replayer
    base_effects : list
        Effects already accepted (held fixed).
    meas_v, base_v : dict
        Measured views and the base model's views (whole record or at least the fitting part).
    fit_sl : slice
        The fitting part.
    sigma : dict
        Noise level per view.
    max_iter : int
        Gauss-Newton steps (smooth models).
    scan_above, scan_s : float
        When the model has a ``grid`` and the cost after the local fit is still above
        ``scan_above`` times its noise expectation (the number of whitened samples), the
        grid is scanned globally on the first ``scan_s`` seconds of the fitting part and the
        best point refined (:func:`_scan`); the better of the two fits is kept.

    Notes
    -----
    A model that is not smooth (``model.smooth`` False, one parameter) is fitted by a bounded
    scalar search of the cost around a first estimate from its linear ``moments``; its
    standard error is that of the moments.
    """
    n_end = fit_sl.stop
    sims = 0

    def model_views(u):
        nonlocal sims
        th = np.clip(model.theta0 + u * model.step, model.lower, model.upper)
        out = replay.run(base_effects + model.build(th), n=n_end)
        sims += 1
        return views(out)

    def res(mv):
        return whitened(meas_v, mv, fit_sl, sigma)

    p = len(model.params)
    r_base = res(base_v)
    cost0 = float(r_base @ r_base)
    lo = (model.lower - model.theta0) / model.step
    hi = (model.upper - model.theta0) / model.step
    null_start = bool(np.all(model.theta0 == 0) or model.fixed.get("null_start"))
    u = np.zeros(p)
    v0 = base_v if null_start else model_views(u)
    r = r_base if null_start else res(v0)
    cost = float(r @ r)

    def jacobian(u, r):
        J = np.empty((len(r), p))
        vs = []
        for i in range(p):
            e = np.zeros(p)
            e[i] = 1.0 if u[i] + 1.0 <= hi[i] else -1.0
            vi = model_views(u + e)
            vs.append(vi)
            J[:, i] = (r - res(vi)) / e[i]      # d(model)/du = -d(residual)/du
        colnorm = np.sqrt(np.sum(J * J, axis=0))
        ident = (colnorm > 1e-6 * max(colnorm.max(), 1e-300)) & (colnorm > 1e-3)
        return J, ident, vs

    J, ident, vs = jacobian(u, r)
    it = 0
    if not model.smooth and p == 1:
        if model.moments is not None:
            m0 = model.moments(v0, fit_sl)
            slope = model.moments(vs[0], fit_sl) - m0
            target = model.moments(meas_v, fit_sl) - m0
            u1 = float(slope @ target / (slope @ slope)) if slope @ slope > 0 else 0.0
            n_fit = fit_sl.stop - fit_sl.start
            se_mom = math.sqrt(np.mean([sigma[k] ** 2 for k in ("c_x", "c_y")]) / n_fit / len(slope))
            se_u = se_mom / math.sqrt(float(slope @ slope) / len(slope)) if slope @ slope > 0 else np.inf
        else:
            u1 = float(J[:, 0] @ r / (J[:, 0] @ J[:, 0])) if ident[0] else 0.0
            se_u = np.inf
        w = max(0.05 * abs(u1), 0.02)
        a, b = max(u1 - w, lo[0]), min(u1 + w, hi[0])
        best = {"cost": cost, "u": 0.0}

        def f(x):
            rr = res(model_views(np.array([x])))
            c = float(rr @ rr)
            if c < best["cost"]:
                best.update(cost=c, u=x)
            return c
        from scipy.optimize import minimize_scalar

        minimize_scalar(f, bounds=(a, b), method="bounded", options={"xatol": max(2e-4 * abs(u1), 2e-4), "maxiter": 20})
        u = np.array([best["u"]])
        cost = best["cost"]
        se = np.array([se_u * model.step[0]])
        theta = np.clip(model.theta0 + u * model.step, model.lower, model.upper)
        return FitResult(model=model, theta=theta, se=se, identifiable=ident, cost0=cost0, cost=cost, n=len(r),
                         sims=sims, iterations=0, effects=model.build(theta))

    lam = 0.0
    rejac = not np.all(ident)
    for it in range(1, max_iter + 1):
        if not np.any(ident):
            break
        Ji = J[:, ident]
        A = Ji.T @ Ji
        g = Ji.T @ r
        d = np.zeros(p)
        d[ident] = np.linalg.solve(A + lam * np.diag(np.diag(A)), g)
        u1 = np.clip(u + d, lo, hi)
        step = u1 - u
        if np.max(np.abs(step)) < 1e-6:
            break
        r1 = res(model_views(u1))
        c1 = float(r1 @ r1)
        # Broyden update of the model Jacobian with the observed change
        dm = r - r1
        J += np.outer(dm - J @ step, step) / float(step @ step)
        if c1 < cost:
            rel = (cost - c1) / max(cost, 1e-300)
            u, r, cost = u1, r1, c1
            lam = lam / 10.0
            if rejac:
                # parameters without sensitivity at the start (the speed of a zero force) join now
                J, ident, _ = jacobian(u, r)
                rejac = False
                continue
            if rel < 1e-7 or np.max(np.abs(step)) < 1e-4:
                break
        else:
            lam = max(lam * 10.0, 1e-3)
    if model.grid is not None and cost > scan_above * len(r):
        u1, _, ns = _scan(replay, base_effects, model, meas_v, fit_sl, sigma, u, lo, hi, scan_s)
        sims += ns
        r1 = res(model_views(u1))
        if float(r1 @ r1) < cost:
            u, r, cost = u1, r1, float(r1 @ r1)
            J, ident, _ = jacobian(u, r)
    n = len(r)
    se = np.full(p, np.inf)
    if np.any(ident):
        Ji = J[:, ident]
        s2 = cost / max(n - int(np.count_nonzero(ident)), 1)
        cov = s2 * np.linalg.pinv(Ji.T @ Ji)
        se[ident] = np.sqrt(np.maximum(np.diag(cov), 0.0)) * model.step[ident]
    theta = np.clip(model.theta0 + u * model.step, model.lower, model.upper)
    return FitResult(model=model, theta=theta, se=se, identifiable=ident, cost0=cost0, cost=cost, n=n,
                     sims=sims, iterations=it, effects=model.build(theta))


def holdout_score(meas_v: dict, base_v: dict, cand_v: dict, hold_sl: slice, sigma: dict) -> dict:
    """Held-out comparison of a candidate with the base model (see module docstring)."""
    r0 = whitened(meas_v, base_v, hold_sl, sigma)
    r1 = whitened(meas_v, cand_v, hold_sl, sigma)
    d = r0 - r1
    nd = float(np.linalg.norm(d))
    dsse = float(r0 @ r0 - r1 @ r1)
    z = dsse / (2 * nd) if nd > 0 else 0.0
    per_view, fracs, worse = {}, [], []
    for v in VIEWS:
        e0 = (meas_v[v][hold_sl] - base_v[v][hold_sl]) / sigma[v]
        e1 = (meas_v[v][hold_sl] - cand_v[v][hold_sl]) / sigma[v]
        m0, m1 = float(np.mean(e0 ** 2)), float(np.mean(e1 ** 2))
        x0, x1 = max(m0 - 1.0, 0.0), max(m1 - 1.0, 0.0)
        frac = (x0 - x1) / x0 if x0 > 0 else 0.0
        per_view[v] = {"ms_before": m0, "ms_after": m1, "explained": frac}
        if m0 > 2.0:                      # rms above sqrt(2) x noise: clearly above
            fracs.append(frac)
        if m1 - m0 > max(0.25, 0.05 * m0):
            worse.append(v)
    return {"z": z, "p": float(stats.norm.sf(z)), "delta_sse": dsse, "explained": float(np.mean(fracs)) if fracs else 0.0,
            "views_worse": worse, "per_view": per_view}
