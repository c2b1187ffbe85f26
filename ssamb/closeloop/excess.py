r"""The held-out misfit a fitted model owes to its own parameter uncertainty.

A model fitted on one part of a record predicts the other part worse than the model with the
true parameters, even when its structure is right: its parameters carry the estimation error the
fitting part's noise left, :math:`\delta = \hat\theta - \theta^\ast`. With :math:`n` the held-out
part's whitened noise and :math:`g = f(\hat\theta) - f(\theta^\ast) \approx J\delta` the
difference of the two predictions there, the truth's advantage

.. math:: D = \lVert g - n\rVert^2 - \lVert n\rVert^2 = \lVert g\rVert^2 - 2 g^T n

has, given :math:`\delta`, mean :math:`\lVert g\rVert^2` and variance :math:`4\lVert g\rVert^2`.
When the model's covariance :math:`\Sigma` is honest (:math:`\delta \sim N(0, \Sigma)`,
independent of the held-out noise), with :math:`A = J\Sigma J^T`,

.. math:: E[D] = \operatorname{tr} A, \qquad \operatorname{Var}[D] = 4\operatorname{tr} A + 2\operatorname{tr} A^2,

the out-of-sample optimism of a fitted model (the argument behind Akaike's criterion, here with
the held-out part's own sensitivity: where the parameters extrapolate -- an unbalance's speed
sets its phase later in the record -- :math:`\operatorname{tr} A` can be far above the number of
parameters). :math:`D` is a quadratic form in the Gaussian parameter error and noise, whose exact
tail :func:`excess_z` computes: large only when the model misses more than its stated
uncertainty allows (a missing effect, or standard errors too small). The improvement test of an effect
(:func:`ssamb.closeloop.fit.improvement_z`) has no such term: there the candidate's own
estimation error only makes it harder to accept.

:func:`parameter_spread` measures :math:`A` by sigma points about the model's parameters, and
takes :math:`\Sigma` from the fitting part's own sensitivities and the priors (the error an
estimate from those data has), not from what the estimator reported: a loose reported covariance
does not excuse a model, and a fit that stopped short of the optimum is found out. The
predictions are means of replays with common seeds; where a chaotic loop's replays part whatever
the parameters, each squared difference is debiased by its jackknife variance over the paired
replays.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..errors import InputError
from .comparison import Comparison, Part

__all__ = ["excess_z", "parameter_spread", "sigma_points", "truth_advantage"]


def sigma_points(cov: np.ndarray, rtol: float = 1e-12) -> np.ndarray:
    r"""Columns :math:`l_i` with :math:`\sum_i l_i l_i^T = \Sigma` (the symmetric square root's
    eigen-directions; directions with no variance left out).

    Examples
    --------
    >>> import numpy as np
    >>> L = sigma_points(np.array([[4.0, 1.0], [1.0, 2.0]]))
    >>> bool(np.allclose(L @ L.T, [[4.0, 1.0], [1.0, 2.0]]))
    True
    """
    c = 0.5 * (np.asarray(cov, float) + np.asarray(cov, float).T)
    w, v = np.linalg.eigh(c)
    keep = w > rtol * max(float(w.max(initial=0.0)), 1e-300)
    return v[:, keep] * np.sqrt(w[keep])


def excess_z(delta_chi2: float, spread: dict, v_jackknife: float = 0.0) -> float:
    r"""The truth's held-out advantage :math:`D` over a fitted model as the normal quantile of its
    tail probability under what the model's parameter uncertainty gives it (module docstring).

    With :math:`s_k^2` the eigenvalues of :math:`A = J\Sigma J^T` (``spread["s2"]``) and
    :math:`u \sim N(0, I)` the parameter error in the eigen-directions,
    :math:`D = \sum_k s_k^2 u_k^2 - 2 s_k u_k n_k` is a quadratic form whose 2x2 blocks have the
    eigenvalues :math:`\lambda_k^\pm = (s_k^2 \pm s_k\sqrt{s_k^2 + 4})/2`: a weighted sum of
    :math:`\chi^2_1` variables, skewed to the right where few directions dominate (the normal
    approximation with the same mean and variance puts 1.7 % of an honest fit beyond 3.09). The
    predictions' own noise adds a normal term of variance :math:`V_J`. The tail
    :math:`P(D' \ge D)` is Imhof's integral (Biometrika 48, 1961), returned as
    :math:`\Phi^{-1}(1 - P)`. Without parameters (``s2`` empty) only the predictions' noise is
    left, :math:`D/\sqrt{V_J}`.

    Examples
    --------
    >>> from ssamb.closeloop.excess import excess_z
    >>> round(excess_z(0.0, {"s2": [1.0]}), 2)      # D = u^2 - 2 u n: P(D >= 0) = 0.65
    -0.38
    >>> round(excess_z(20.0, {"s2": [1.0]}), 1)      # a normal approximation would say 3.5
    3.4
    """
    s2 = np.asarray(spread.get("s2", []), float)
    s2 = s2[s2 > 0]
    if s2.size == 0:
        return float(delta_chi2 / math.sqrt(v_jackknife)) if v_jackknife > 0 else 0.0
    root = np.sqrt(s2 * (s2 + 4.0))
    lam = np.concatenate([(s2 + root) / 2, (s2 - root) / 2])
    p = _imhof_tail(float(delta_chi2), lam, float(v_jackknife))
    return float(stats.norm.isf(min(max(p, 1e-300), 1.0)))


def _imhof_tail(x: float, lam: np.ndarray, var_normal: float = 0.0) -> float:
    r""":math:`P(\sum_k \lambda_k \chi^2_{1,k} + \sigma Z > x)` by Imhof's formula:
    :math:`\tfrac12 + \tfrac1\pi\int_0^\infty \sin\theta(u) / (u\rho(u))\,du` with
    :math:`\theta = \tfrac12\sum_k\arctan(\lambda_k u) - \tfrac12 xu`,
    :math:`\rho = \prod_k(1 + \lambda_k^2u^2)^{1/4}\,e^{\sigma^2u^2/8}`."""
    import warnings

    from scipy import integrate

    scale = float(np.max(np.abs(lam)))
    lam_s, x_s, v_s = lam / scale, x / scale, var_normal / scale ** 2
    w = 0.5 * x_s                                   # theta = a(u) - w u, a(u) slowly varying

    def env(u):                                     # 1 / (u rho(u))
        return math.exp(-0.25 * float(np.sum(np.log1p((lam_s * u) ** 2))) - v_s * u * u / 8.0) / u

    def a(u):
        return 0.5 * float(np.sum(np.arctan(lam_s * u)))

    def f(u):
        return 0.5 * (float(np.sum(lam_s)) - x_s) if u == 0.0 else math.sin(a(u) - w * u) * env(u)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        if w <= 0.0:                                # no oscillation: the integrand decays absolutely
            total = integrate.quad(f, 0.0, np.inf, limit=400)[0]
        else:                                       # beyond a few periods, a Fourier integral (QAWF)
            edge = 20.0 / w
            total = integrate.quad(f, 0.0, edge, limit=800)[0]
            total += integrate.quad(lambda u: math.sin(a(u)) * env(u), edge, np.inf, weight="cos", wvar=w)[0]
            total -= integrate.quad(lambda u: math.cos(a(u)) * env(u), edge, np.inf, weight="sin", wvar=w)[0]
    return min(max(0.5 + total / math.pi, 0.0), 1.0)


def parameter_spread(cmp: Comparison, point: tuple, scales: tuple) -> dict:
    r"""How far a model's held-out predictions move over the parameter error its fitting part
    leaves (module docstring).

    ``point`` is ``(theta, cov, build, prior_sd)``: the model's parameter vector, the estimator's
    covariance (only its directions and scale matter: the sigma points), ``build(theta) ->
    (overrides, effects)`` and the parameters' prior standard deviations (``inf`` without a
    prior); ``scales`` the per-entry factors of the fitting and held-out parts' residuals.

    The sigma points :math:`\hat\theta \pm l_i` (:func:`sigma_points` of the covariance) are
    replayed; their differences on the fitting part give its information in the coordinates
    :math:`u` of :math:`\theta = \hat\theta + Lu`, :math:`F = G_f G_f^T` (debiased by the replays'
    own noise on the diagonal), and the prior's, :math:`L^T P L`; the error an estimate from that
    part has is :math:`u \sim N(0, \Sigma_u)`, :math:`\Sigma_u = (F + L^TPL)^{-1}`, whatever the
    estimator reported (an estimator that states a loose covariance is not excused by it, and one
    that stopped short of the optimum is found out). On the held-out part,
    :math:`A = G_h^T\Sigma_u G_h`. Returns ``tr_a``, ``s2`` (the eigenvalues of :math:`A`),
    ``points`` (sigma points replayed) and ``dropped`` (those whose replays mostly touch a stop,
    or that leave a parameter's domain: left out, a direction then measured from its other side).
    """
    from .fit import _leave_one_out

    theta, cov, build, prior_sd = point
    theta = np.asarray(theta, float)
    L = sigma_points(cov)
    parts = (cmp.fit, cmp.hold)
    ov0, eff0 = build(theta)
    pred0 = cmp.prediction(ov0, eff0)
    r0 = [cmp.residual(pt, pred0) * sc for pt, sc in zip(parts, scales)]
    jk0 = [_jackknife(cmp, pt, ov0, eff0, sc, _leave_one_out) for pt, sc in zip(parts, scales)]
    cols, bias, dropped = ([], []), ([], []), 0
    for i in range(L.shape[1]):
        side = []
        for sgn in (1.0, -1.0):
            try:                    # a point beyond a parameter's domain (a delay below zero) is left out
                ov, eff = build(theta + sgn * L[:, i])
                pred = cmp.prediction(ov, eff)
            except InputError:
                dropped += 1
                continue
            if pred.get("delevitated_share", 0.0) > 0.5:
                dropped += 1
                continue
            side.append([(cmp.residual(pt, pred) * sc - r,
                          _debias(j0, _jackknife(cmp, pt, ov, eff, sc, _leave_one_out)))
                         for pt, sc, r, j0 in zip(parts, scales, r0, jk0)])
        for k in range(2):
            if len(side) == 2:
                cols[k].append((side[0][k][0] - side[1][k][0]) / 2)
                bias[k].append((side[0][k][1] + side[1][k][1]) / 4)
            elif side:              # one side: its difference (the sign does not enter A)
                cols[k].append(side[0][k][0])
                bias[k].append(side[0][k][1])
            else:
                cols[k].append(np.zeros(len(r0[k])))
                bias[k].append(0.0)
    if not cols[0]:
        return {"tr_a": 0.0, "s2": [], "points": 0, "dropped": dropped}
    Gf, Gh = np.array(cols[0]), np.array(cols[1])
    F = Gf @ Gf.T - np.diag(bias[0])
    prec = np.where(np.isfinite(prior_sd), 1.0 / np.asarray(prior_sd, float) ** 2, 0.0)
    info = 0.5 * (F + F.T) + L.T @ (prec[:, None] * L)
    w, v = np.linalg.eigh(info)
    keep = w > 1e-9 * max(float(w.max(initial=0.0)), 1e-300)
    root = v[:, keep] / np.sqrt(w[keep])                 # Sigma_u = root root^T
    H = Gh @ Gh.T - np.diag(bias[1])
    s2 = np.clip(np.linalg.eigvalsh(root.T @ (0.5 * (H + H.T)) @ root), 0.0, None)
    return {"tr_a": float(s2.sum()), "s2": s2.tolist(), "points": 2 * L.shape[1], "dropped": dropped}


def _jackknife(cmp: Comparison, part: Part, overrides: dict, effects: list, scale: np.ndarray,
               loo) -> np.ndarray | None:
    """A model's scaled leave-one-replay-out residuals (memoised as the held-out test keeps them)."""
    r = cmp.memoised("jackknife", part, overrides, effects, lambda: loo(cmp, part, overrides, effects))
    return None if r is None else np.array([x * scale for x in r])


def _debias(a: np.ndarray | None, b: np.ndarray | None) -> float:
    r"""The expected :math:`\lVert \bar b - \bar a\rVert^2` the paired replays' own noise adds:
    the jackknife variance of the difference summed over entries (0 without replays to pair)."""
    if a is None or b is None or len(a) != len(b):
        return 0.0
    d = b - a
    m = len(d)
    return float((m - 1) / m * np.sum((d - d.mean(axis=0)) ** 2))


def truth_advantage(cmp: Comparison, final, point: tuple | None, pred: dict, overrides: dict, effects: list,
                    settings) -> dict:
    """How much better a known truth (``overrides``, ``effects``, its prediction ``pred``) predicts
    the held-out part than the ``final`` model (:class:`ssamb.closeloop.fit.Base`) whose parameter
    point is ``point`` (:func:`ssamb.closeloop.search.final_point`): the held-out comparison
    (:func:`ssamb.closeloop.fit.holdout_score`, its ``z`` the improvement statistic), the model's
    ``spread`` (:func:`parameter_spread`) and ``z_excess`` (:func:`excess_z`; the improvement
    statistic where the model has no parameter point). A test's oracle: only a suite or a test
    knows the truth."""
    from .fit import _scale, holdout_score, jackknife_variance, replay_jackknife

    hs = holdout_score(cmp, final, pred, overrides, effects, 0, settings)
    if point is None:
        return {**hs, "spread": None, "z_excess": hs["z"]}
    s = _scale(cmp, cmp.hold, final, overrides, effects)
    spread = parameter_spread(cmp, point, (_scale(cmp, cmp.fit, final, final.overrides, final.effects), s))
    jk = replay_jackknife(cmp, cmp.hold, final, overrides, effects, s)
    return {**hs, "spread": spread, "z_excess": excess_z(hs["delta_chi2"], spread, jackknife_variance(jk))}
