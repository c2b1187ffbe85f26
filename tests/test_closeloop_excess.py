"""Tests of ssamb.closeloop.excess: the held-out misfit a fitted model owes to its parameter
uncertainty, on linear Gaussian models where every quantity is known in closed form."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from ssamb.closeloop.excess import excess_z, sigma_points


def _spd(rng, p):
    a = rng.standard_normal((p, p))
    return a @ a.T + 0.1 * np.eye(p)


@pytest.mark.parametrize("p", [1, 3, 6])
def test_sigma_points_rebuild_the_covariance(p):
    cov = _spd(np.random.default_rng(p), p)
    L = sigma_points(cov)
    assert L.shape == (p, p)
    np.testing.assert_allclose(L @ L.T, cov, rtol=1e-10, atol=1e-12)


def test_sigma_points_leave_out_directions_without_variance():
    v = np.array([[1.0], [2.0], [0.5]])
    L = sigma_points(v @ v.T)
    assert L.shape == (3, 1)
    np.testing.assert_allclose(L @ L.T, v @ v.T, atol=1e-12)


def _draws(extrapolate: float, n_draws: int = 4000, seed: int = 0):
    """A linear model fitted by least squares on one part, judged on another whose sensitivity to
    two of its parameters is ``extrapolate`` times larger (a frequency sets a phase that grows
    with time); per draw the truth's held-out advantage ``D``, the improvement statistic without
    the parameters' share, and the spread the fit's covariance gives."""
    rng = np.random.default_rng(seed)
    n, p = 120, 5
    J_fit = rng.standard_normal((n, p))
    J_hold = rng.standard_normal((n, p)) * np.r_[extrapolate, extrapolate, 1.0, 1.0, 1.0]
    cov = np.linalg.inv(J_fit.T @ J_fit)           # the least-squares covariance: honest
    G = (J_hold @ sigma_points(cov)).T              # the sigma points' prediction differences
    spread = {"tr_a": float(np.sum(G * G)), "s2": np.linalg.eigvalsh(G @ G.T).tolist()}
    d, z_imp = np.empty(n_draws), np.empty(n_draws)
    for k in range(n_draws):
        delta = np.linalg.solve(J_fit.T @ J_fit, J_fit.T @ rng.standard_normal(n))   # the fit's error
        noise = rng.standard_normal(n)
        g = J_hold @ delta
        d[k] = float((g - noise) @ (g - noise) - noise @ noise)
        z_imp[k] = d[k] / np.sqrt(4 * g @ g)
    return d, z_imp, spread


@pytest.mark.parametrize("extrapolate", [1.0, 6.0])
def test_the_truths_advantage_over_an_honest_fit_is_as_likely_as_excess_z_says(extrapolate):
    d, z_imp, spread = _draws(extrapolate)
    s2 = np.asarray(spread["s2"])
    mean, sd = s2.sum(), np.sqrt(4 * s2.sum() + 2 * np.sum(s2 ** 2))
    assert abs((d.mean() - mean) / sd) < 0.06 and abs(d.std() / sd - 1) < 0.06, (d.mean(), mean, d.std(), sd)
    z_crit = stats.norm.isf(1e-2)
    tail = d[d > mean + 1.5 * sd]                   # the others are far inside
    beyond = sum(excess_z(x, spread) > z_crit for x in tail) / len(d)
    assert 0.5e-2 < beyond < 1.6e-2, beyond         # 1 % expected; 4000 draws: sd 0.16 %
    # the normal approximation with the same mean and variance puts too many beyond
    assert np.mean((d - mean) / sd > z_crit) > 1.3 * beyond
    # without the parameters' share the truth looks better than the fit by about sqrt(tr A) / 2
    assert z_imp.mean() > 0.3 * np.sqrt(mean), (z_imp.mean(), mean)


def test_a_missing_effect_is_beyond_the_parameters_uncertainty():
    """The same fit with a signal the model lacks on the held-out part: the test sees it."""
    rng = np.random.default_rng(3)
    n, p = 120, 5
    J_fit, J_hold = rng.standard_normal((n, p)), rng.standard_normal((n, p))
    cov = np.linalg.inv(J_fit.T @ J_fit)
    G = (J_hold @ sigma_points(cov)).T
    spread = {"tr_a": float(np.sum(G * G)), "s2": np.linalg.eigvalsh(G @ G.T).tolist()}
    missing = 1.0 * np.sin(np.linspace(0, 20, n))       # chi-square about 60 over 120 entries
    hits = 0
    for _ in range(200):
        delta = np.linalg.solve(J_fit.T @ J_fit, J_fit.T @ rng.standard_normal(n))
        noise = rng.standard_normal(n)
        g = J_hold @ delta + missing
        hits += excess_z(float((g - noise) @ (g - noise) - noise @ noise), spread) > stats.norm.isf(1e-3)
    assert hits / 200 > 0.9


def test_the_final_point_rebuilds_the_final_model_and_the_truth_is_within_its_spread():
    """On the toy device (a first-order plant under PI control, tests/test_closeloop_toy.py), whose
    replays are smooth in its parameters: the final model's parameter point rebuilds the final
    model; the held-out spread an estimate of its two parameters leaves is of the order of two
    (the held-out part is another stretch of the same experiment); the truth is not ahead of the
    final model beyond it."""
    from test_closeloop_toy import CFG, Toy, _data

    from ssamb.closeloop import _analyse
    from ssamb.closeloop.excess import truth_advantage
    from ssamb.closeloop.fit import Base

    truth_ov, truth_eff = {"plant.b_gain": 1.08}, [{"name": "bias", "force_n": 0.3}]
    arrays = _data({"plant": {"a": 0.95, "b_gain": 1.08}}, truth_eff)
    rep, art = _analyse(arrays, {}, CFG, device=Toy())
    cmp, search = art["comparison"], art["search"]
    assert [e["name"] for e in rep["effects"]] == ["bias"]
    theta, cov, build, prior = search.joint["point"]
    assert len(theta) == 2 and cov.shape == (2, 2) and np.isfinite(prior[0]) and np.isinf(prior[1])
    ov, eff = build(theta)
    assert ov == pytest.approx(search.overrides) and eff == search.effects
    adv = truth_advantage(cmp, Base(search.overrides, search.effects, search.final), search.joint["point"],
                          cmp.prediction(truth_ov, truth_eff), truth_ov, truth_eff, art["settings"])
    assert 0.2 < adv["spread"]["tr_a"] < 8.0, adv["spread"]
    assert adv["spread"]["dropped"] == 0 and adv["spread"]["points"] == 4
    assert adv["z_excess"] < stats.norm.isf(1e-3), adv["z_excess"]


class _Linear:
    """A comparison whose prediction is linear in one parameter (no replay noise): enough of
    :class:`ssamb.closeloop.comparison.Comparison` for :func:`parameter_spread`."""

    def __init__(self, j_fit, j_hold):
        self.fit, self.hold = "fit", "hold"
        self.j = {"fit": np.asarray(j_fit, float), "hold": np.asarray(j_hold, float)}

    def prediction(self, overrides, effects):
        return {"theta": overrides["theta"], "delevitated_share": 0.0}

    def residual(self, part, pred):
        return self.j[part] * pred["theta"]

    def memoised(self, kind, part, overrides, effects, compute):
        return None                                 # no replays to pair: nothing to debias


def test_a_sigma_point_beyond_a_parameters_domain_is_measured_from_its_other_side():
    """A delay of 0.1 sd above zero: the point below zero leaves the domain (the effect refuses
    it); the direction is measured from the point above, and the spread is the linear one."""
    from ssamb.closeloop.excess import parameter_spread
    from ssamb.errors import InputError

    def build(t):
        if t[0] < 0:
            raise InputError("delay_s must be in [0, 2.5e-3) s")
        return {"theta": float(t[0])}, []
    cmp = _Linear(np.ones(50), 2 * np.ones(20))     # information 50 on the fitting part; 4 x 20 held out
    sd = 0.2
    out = parameter_spread(cmp, (np.array([0.1 * sd]), np.array([[sd ** 2]]), build, np.array([np.inf])),
                           (np.ones(50), np.ones(20)))
    assert out["dropped"] == 1 and out["points"] == 2
    assert out["tr_a"] == pytest.approx(80 / 50)    # J_h^2 / J_f^2, whatever sd the estimator reported
