"""The statistics of close the loop on cases with known answers: features and their noise,
the estimator on a noisy simulator, identifiability, and fits that must not crash."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ssamb.closeloop.calibration import identifiability
from ssamb.closeloop.estimate import EstimateSettings, Problem, map_fit
from ssamb.closeloop.models import EffectModel, basin_points
from ssamb.closeloop.features import Whitener, _band_cov, features, line_phasors, make_layout
from ssamb.closeloop.spectra import make_frame

FS = 8000.0
P_LEN = 1600          # samples per period (0.2 s at 8 kHz): lines every 5 Hz


def _frame(periods: int = 8, lines_hz=(10.0, 25.0, 40.0)):
    n = periods * P_LEN
    t = np.arange(n) / FS
    exc = sum(np.sin(2 * np.pi * f * t + 0.3 * i) for i, f in enumerate(lines_hz))
    return make_frame(FS, 0, n, {"x": exc}, P_LEN, np.asarray(lines_hz)), t


#: seven views, as the AMB's cost views
NAMES = ("x_meas", "d_x", "c_x", "y_ss", "y_meas", "d_y", "c_y")


def _views(x: np.ndarray) -> dict:
    return {v: x[i] for i, v in enumerate(NAMES)}


def test_offgrid_covariance_of_correlated_white_noise():
    """White noise of variance s^2 in two views with correlation c: E X X^H = n s^2 [[1, c], [c, 1]]."""
    fr, t = _frame()
    rng = np.random.default_rng(1)
    n, s, c = fr.n, 2.0e-3, 0.6
    a, b = rng.standard_normal((2, n))
    x = np.zeros((7, n))
    x[0], x[1] = s * a, s * (c * a + math.sqrt(1 - c * c) * b)
    x[2:] = s * rng.standard_normal((5, n))
    f = features(make_layout(fr, {"x": np.zeros(n)}, views=NAMES), _views(x))
    C = np.mean(f.cov_bins, axis=0) / (n * s * s)
    assert C[0, 0].real == pytest.approx(1.0, rel=0.1) and C[1, 1].real == pytest.approx(1.0, rel=0.1)
    assert C[0, 1].real == pytest.approx(c, abs=0.08)


def test_band_covariance_ignores_a_line():
    """A line 1000 times the noise power in one off-grid bin does not raise the band's floor."""
    rng = np.random.default_rng(2)
    Y = (rng.standard_normal((1, 400)) + 1j * rng.standard_normal((1, 400))) / math.sqrt(2)
    Y[0, 200] = 1000.0
    C = _band_cov(Y, np.ones(400, bool), n_bands=4, min_bins=24)
    assert 0.8 < C[200, 0, 0].real < 1.2


@pytest.mark.parametrize("f_hz", [15.0, 37.3])
def test_line_phasor_on_and_off_the_grid(f_hz):
    """A sinusoid a cos + b sin at a grid frequency (15 Hz) or between grid lines (37.3 Hz), on top
    of a periodic response: its phasor n/2 (a - jb) comes back (the periodic part projected out)."""
    fr, t = _frame()
    a, b = 0.7, -0.4
    periodic = np.sin(2 * np.pi * 10.0 * t) + 0.5 * np.cos(2 * np.pi * 45.0 * t)
    x = (a * np.cos(2 * np.pi * f_hz * t) + b * np.sin(2 * np.pi * f_hz * t) + (f_hz != 15.0) * periodic)[None]
    A = line_phasors(fr, x, [f_hz])[0, 0]
    assert A == pytest.approx(0.5 * fr.n * (a - 1j * b), rel=1e-3)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(c=st.floats(-0.9, 0.9), ratio=st.floats(0.1, 10.0))
def test_whitened_difference_has_unit_variance(c, ratio):
    """Measured minus modelled features of two independent noise realisations, whitened with the
    sum of their covariances: unit variance per entry (within the sampling error)."""
    fr, t = _frame(periods=10)
    n = fr.n
    rng = np.random.default_rng(7)
    lay = make_layout(fr, {"x": np.zeros(n)}, views=NAMES)
    sets = []
    for scale in (1.0, ratio):
        a, b = rng.standard_normal((2, n))
        x = 1e-3 * scale * rng.standard_normal((7, n))
        x[3], x[4] = 1e-3 * scale * a, 1e-3 * scale * (c * a + math.sqrt(1 - c * c) * b)
        sets.append(features(lay, _views(x), factors=(np.ones(7), np.ones(7))))
    W = Whitener.build(lay, sets[0], sets[1], ridge=0.0)
    r = W.residual(sets[0], sets[1])
    assert 0.5 < np.mean(r ** 2) < 1.6


# -- the estimator on a noisy "simulator" ---------------------------------------------------
def _linear_problem(rng_data, p_true, B, prior_sd, rho: float = 0.6, n_data_noise: float = 0.6):
    """r(theta, seed) = B (theta - theta*) + e_data + e_model(seed): the model's own noise is fresh
    at every evaluation (a chaotic replay), the data's fixed."""
    e_data = math.sqrt(n_data_noise) * rng_data.standard_normal(B.shape[0])

    def evaluate(theta, seed):
        e_m = math.sqrt(rho) * np.random.default_rng(seed).standard_normal(B.shape[0])
        return B @ (np.asarray(theta) - p_true) + e_data + e_m
    p = B.shape[1]
    return Problem(names=tuple(f"p{i}" for i in range(p)), theta0=np.zeros(p), prior_sd=prior_sd,
                   step=np.where(np.isfinite(prior_sd), prior_sd, 0.1), lower=np.full(p, -10.0), upper=np.full(p, 10.0),
                   evaluate=evaluate, groups=[np.arange(B.shape[0])])


def test_map_fit_recovers_truth_with_honest_errors():
    """Noisy linear-Gaussian simulator: 4 parameters, two of them nearly confounded (columns at
    0.98 correlation), one the data do not see. Over 12 data sets the identified estimates lie
    within their standard errors as a standard normal would (rms of the z-scores 0.5-1.5, none
    beyond 3.5), and the unseen parameter stays at its prior with its prior's standard error."""
    rng = np.random.default_rng(11)
    N = 200
    B = np.zeros((N, 4))
    B[:, 0] = 40.0 * rng.standard_normal(N) / math.sqrt(N)
    B[:, 1] = 60.0 * rng.standard_normal(N) / math.sqrt(N)
    B[:, 2] = 0.98 * B[:, 1] + 0.2 * 60.0 * rng.standard_normal(N) / math.sqrt(N)
    prior = np.array([1.0, 1.0, 1.0, 0.5])
    z = []
    for k in range(12):
        truth = rng.uniform(-1.0, 1.0, 4) * prior
        fit = map_fit(_linear_problem(np.random.default_rng(100 + k), truth, B, prior), EstimateSettings())
        ident = identifiability(fit.info, prior, tuple("p0 p1 p2 p3".split()), 1 / 3, cov=fit.cov)["per_parameter"]
        for i in range(3):
            if ident[f"p{i}"]["identified"]:
                z.append((fit.theta[i] - truth[i]) / fit.se[i])
        assert not ident["p3"]["identified"] and "barely depend" in ident["p3"]["reason"]
        assert fit.theta[3] == pytest.approx(0.0, abs=0.05) and fit.se[3] == pytest.approx(0.5, rel=0.1)
    z = np.asarray(z)
    assert len(z) >= 24
    assert 0.5 < math.sqrt(np.mean(z ** 2)) < 1.5 and np.max(np.abs(z)) < 3.5


def test_a_fit_that_drifts_up_within_the_noise_returns_to_its_best_centre():
    """:func:`ssamb.closeloop.estimate.map_fit` on a simulator whose residual gains a common offset
    growing with every evaluation once the fit is near its optimum, and a tolerance it never
    meets: each step is accepted within the cost's noise while the centres' cost climbs; when the
    iterations run out the last centre costs significantly more than the best visited, and the
    estimate is that best centre (its cost the lowest of the iterations', near the truth), which
    :func:`ssamb.closeloop.search.optimum_of` reports. Without the drift nothing returns."""
    from ssamb.closeloop.search import optimum_of

    rng = np.random.default_rng(3)
    n = 200
    B = 30.0 * rng.standard_normal((n, 2)) / math.sqrt(n)
    e_data = 0.7 * rng.standard_normal(n)
    truth = np.array([0.5, -0.3])
    for drift in (0.03, 0.0):
        calls = [0]

        def evaluate(theta, seed, drift=drift, calls=calls):
            calls[0] += 1
            e_m = 0.7 * np.random.default_rng(seed).standard_normal(n)
            return B @ (np.asarray(theta) - truth) + e_data + e_m + drift * math.sqrt(max(calls[0] - 20, 0))
        prob = Problem(names=("a", "b"), theta0=np.zeros(2), prior_sd=np.ones(2), step=np.ones(2),
                       lower=np.full(2, -10.0), upper=np.full(2, 10.0), evaluate=evaluate, groups=[np.arange(n)])
        fit = map_fit(prob, EstimateSettings(max_iter=12, tol=1e-6))
        costs = [h["chi2"] for h in fit.history if "chi2" in h]
        back = fit.history[-1]["returned_to_best"]
        if drift:
            assert back is not None and costs[-1] > back and fit.chi2 == pytest.approx(back)
            assert back <= min(costs) and "returned" in optimum_of(fit, 1.0)["how"]
        else:
            assert back is None
        assert np.all(np.abs(fit.theta - truth) < 0.05)


def test_identifiability_names_the_confounded_partner():
    """Information of two parameters that only their sum affects, and one without any: the pair
    is confounded (each named as the other's partner), the third has no sensitivity."""
    g = np.array([1.0, 1.0, 0.0])
    info = 1e6 * np.outer(g, g) + np.diag([1e-3, 1e-3, 0.0])
    out = identifiability(info, np.array([0.03, 0.03, 0.05]), ("m", "k", "r"), 1 / 3)["per_parameter"]
    assert not out["m"]["identified"] and "confounded with k" in out["m"]["reason"]
    assert not out["k"]["identified"] and "confounded with m" in out["k"]["reason"]
    assert not out["r"]["identified"] and "barely depend" in out["r"]["reason"]


@pytest.mark.parametrize("case", ["no_sensitivity", "start_on_bound", "start_outside_bounds", "zero_start_column"])
def test_map_fit_degenerate_starts_do_not_crash(case):
    """Every path of the estimator with a degenerate start or bracket: a finite estimate within
    the bounds and a covariance with no NaN (the bracket crash of issue 13 cannot recur)."""
    N = 60
    rng = np.random.default_rng(5)
    if case == "no_sensitivity":
        def evaluate(theta, seed):
            return 0.1 * np.random.default_rng(seed).standard_normal(N)
    else:
        col = rng.standard_normal(N)

        def evaluate(theta, seed):
            gain = theta[1] if case == "zero_start_column" else 1.0      # no sensitivity to theta[0] at theta[1] = 0
            return col * gain * (theta[0] - 0.3) + 0.1 * np.random.default_rng(seed).standard_normal(N)
    lower, upper = np.array([0.0, -1.0]), np.array([1.0, 1.0])
    start = {"start_on_bound": np.array([0.0, 0.5]), "start_outside_bounds": np.array([2.0, 5.0]),
             "zero_start_column": np.array([0.5, 0.0])}.get(case, np.array([0.5, 0.5]))
    prob = Problem(("a", "b"), np.array([0.5, 0.5]), np.array([np.inf, np.inf]), np.array([0.1, 0.1]), lower, upper,
                   evaluate, start=start)
    fit = map_fit(prob, EstimateSettings(max_iter=5))
    assert np.all(np.isfinite(fit.theta)) and np.all((fit.theta >= lower) & (fit.theta <= upper))
    assert not np.any(np.isnan(fit.cov))


def test_condition_of_a_singular_information_is_unbounded():
    """Singular values down to round-off give no condition number; a regular set gives
    the ratio of the largest to the smallest (here 1e3 / 1e-1)."""
    from ssamb.closeloop.calibration import _condition
    assert _condition(np.array([1e3, 1.0, 1e-14])) is None
    assert _condition(np.array([1e3, 1.0, 1e-1])) == pytest.approx(1e4)


def test_a_parameter_on_its_bound_does_not_freeze_the_others():
    """Three parameters, the first starting on its lower bound with the data pulling it further
    out: it stays on the bound, and the other two reach their truth (the whole step used to be
    shortened to zero, freezing a joint refit)."""
    N = 120
    rng = np.random.default_rng(2)
    B, e = 10.0 * rng.standard_normal((N, 3)), rng.standard_normal(N)     # whitened: unit data noise
    truth = np.array([-0.5, 0.4, -0.3])

    def evaluate(theta, seed):
        return B @ (np.asarray(theta) - truth) - e + 0.3 * np.random.default_rng(seed).standard_normal(N)

    prob = Problem(("a", "b", "c"), np.zeros(3), np.full(3, np.inf), np.full(3, 0.05), np.array([0.0, -1.0, -1.0]),
                   np.ones(3), evaluate)
    fit = map_fit(prob, EstimateSettings(max_iter=8))
    assert fit.theta[0] == 0.0
    # with a held at 0 instead of -0.5 the best b, c are the least-squares fit of the rest
    bc = np.linalg.lstsq(B[:, 1:], B[:, 1:] @ truth[1:] + B[:, 0] * truth[0] + e, rcond=None)[0]
    assert np.allclose(fit.theta[1:], bc, atol=3 * fit.se[1:]), (fit.theta, bc, fit.se)
    assert np.all(fit.se[1:] < 0.02)


@pytest.mark.parametrize("structure, lo, hi", [(0.0, 0.999, 1.15), (2.0, 1.9, 2.4)])
def test_misfit_scales_the_reported_errors(structure, lo, hi):
    """A residual with structure the model lacks (rms 2 on unit noise: reduced chi-square about
    5) raises the reported standard errors by about sqrt(5); at the noise it leaves them."""
    N = 400
    rng = np.random.default_rng(8)
    B, e = 8.0 * rng.standard_normal((N, 2)), rng.standard_normal(N)
    struct = structure * math.sqrt(2) * np.sin(0.37 * np.arange(N))

    def evaluate(theta, seed):
        return B @ np.asarray(theta) - e - struct + 0.2 * np.random.default_rng(seed).standard_normal(N)

    prob = Problem(("a", "b"), np.zeros(2), np.full(2, np.inf), np.full(2, 0.05), np.full(2, -1.0), np.ones(2),
                   evaluate, groups=[np.arange(N)])
    fit = map_fit(prob, EstimateSettings())
    ratio = fit.se_misfit / fit.se
    assert np.all((ratio > lo) & (ratio < hi)), ratio


def test_correlated_replay_noise_reaches_the_errors():
    """Every replay (and the data, one more) carries its own random shift along the first
    parameter's column -- noise correlated across all entries, as a replay's hysteresis state
    moves a whole view: over 12 data sets the first parameter's reported z-scores stay honest (rms 0.5-1.6;
    with the diagonal noise model alone 5.7)."""
    rng = np.random.default_rng(21)
    N, tau = 200, 0.05
    B = 10.0 * rng.standard_normal((N, 2))
    z = []
    for k in range(12):
        truth = rng.uniform(-0.3, 0.3, 2)
        d = np.random.default_rng(500 + k)
        e_data = d.standard_normal(N) + tau * d.standard_normal() * B[:, 0]

        def evaluate(theta, seed, truth=truth, e_data=e_data):
            g = np.random.default_rng(seed)
            return (B @ (np.asarray(theta) - truth) - e_data + 0.3 * g.standard_normal(N)
                    + tau * g.standard_normal() * B[:, 0])

        prob = Problem(("a", "b"), np.zeros(2), np.full(2, np.inf), np.full(2, 0.05), np.full(2, -2.0), np.full(2, 2.0),
                       evaluate, seed0=1 + 1000 * k, groups=[np.arange(N)])
        fit = map_fit(prob, EstimateSettings())
        z.append((fit.theta[0] - truth[0]) / fit.se_misfit[0])
    rms = math.sqrt(np.mean(np.square(z)))
    assert 0.5 < rms < 1.6, z


@pytest.mark.parametrize("truth", [2.0e-6, None])
def test_coarse_start_of_a_dead_time(truth):
    """A dead time far beyond its finite-difference step: the coarse grid starts the fit next to
    it; with data that do not depend on it the plain start stays."""
    from ssamb.closeloop.fit import _coarse_start

    m = _amb_model("amplifier_deadtime", {})
    v = np.random.default_rng(3).standard_normal(300)

    def evaluate(theta, seed):
        noise = np.random.default_rng(seed).standard_normal(300)
        if truth is None:
            return noise
        return 40.0 * (np.sqrt(theta[-1] / 1e-6) - np.sqrt(truth / 1e-6)) * v + noise

    prob = Problem(m.params, m.theta0, np.full(1, np.inf), m.step, m.lower, m.upper, evaluate, start=m.theta0.copy())
    start = _coarse_start(prob, m, 0)
    assert start[0] == (truth if truth is not None else 0.0)


def test_excess_of_a_replicate_covariance():
    """Replicates with 5x the variance the diagonal model gives along one direction (and the
    same along the other): the excess is 4x that direction's variance, nothing elsewhere; a
    covariance within its sampling noise (chi-square 95 % of 7 dof: 2.01) adds nothing."""
    from ssamb.closeloop.estimate import _excess

    M = np.array([[2.0, 0.5], [0.5, 1.0]])
    w, V = np.linalg.eigh(M)
    R = V * np.sqrt(w)                                       # M = R R^T
    S = R @ np.diag([5.0, 1.0]) @ R.T
    assert np.allclose(_excess(S, M, 7), R[:, :1] @ R[:, :1].T * 4.0)
    assert np.allclose(_excess(1.9 * M, M, 7), 0.0)


def test_size_statistic_of_an_effect_against_zero():
    """Wald statistic over the effect's size parameters only (a parameter beside them, a spin
    speed say, does not count); a size within its error is not an effect."""
    from ssamb.closeloop.search import size_statistic

    w, k = size_statistic(np.array([3.0, 4.0]), np.eye(2), ["fx_n", "fy_n"])
    assert k == 2 and w == pytest.approx(25.0)
    c = np.array([[1.0, 0.5], [0.5, 1.0]])                 # correlated errors: the full quadratic form
    assert size_statistic(np.array([1.0, -1.0]), c, ["a", "b"])[0] == pytest.approx(4.0)
    w0, _ = size_statistic(np.array([0.06]), np.array([[1e12]]), ["fy_n"])
    assert w0 < 1e-10
    unb = _amb_model("unbalance", {"speed_hz": 50.0})
    assert unb.params == unb.size_params == ("me_cos_kgm", "me_sin_kgm")
    params = unb.params + ("speed_hz",)
    w, k = size_statistic(np.array([2e-5, 0.0, 50.0]), np.diag([1e-10, 1e-10, 1e-4]), params, unb.size_params)
    assert k == 2 and w == pytest.approx(4.0)
    # one size parameter determined (34 errors from zero), the other left at an unestimated
    # parameter's placeholder variance: the effect is not null (a suite draw's unbalance had been
    # dropped so), and W does not depend on the units
    th, c = np.array([-1.18e-5, -5.07e-6, 112.0]), np.diag([3.5e-7 ** 2, 4.0, 1e-6])
    w, k = size_statistic(th, c, params, unb.size_params)
    assert k == 2 and w == pytest.approx((1.18e-5 / 3.5e-7) ** 2, rel=1e-6)
    scale = np.array([1e6, 1e3, 1.0])
    assert size_statistic(th * scale, c * np.outer(scale, scale), params, unb.size_params)[0] == pytest.approx(w)


def test_joint_refit_starts_where_the_effects_were_found():
    """Once effects are found the joint refit starts the identified (free) parameters at their
    values in the base and every other one -- conflicting or unidentified, either may have
    absorbed the effect -- at its prior mean; without an effect, from the calibration."""
    from types import SimpleNamespace

    from ssamb.closeloop.calibration import Calibration, ParameterSpec
    from ssamb.closeloop.fit import Base
    from ssamb.closeloop.search import joint_start

    specs = [ParameterSpec(k, 1.0, True, 0.03) for k in ("a", "b", "c", "d")]
    fit = SimpleNamespace(theta=np.array([0.01, 0.2, -0.02, 0.005]))
    cal = Calibration(specs, fit, {}, ["b"])
    base = Base({}, [], {}, [specs[0]], np.array([0.011]), [specs[2], specs[3]], np.array([-0.03, 0.004]))
    assert joint_start(cal, base, [0], [2, 3], True).tolist() == [0.011, 0.0, 0.0, 0.0]
    assert joint_start(cal, base, [0], [2, 3], False).tolist() == [0.011, 0.2, -0.03, 0.004]


def test_an_effect_the_joint_refit_leaves_at_zero_is_dropped():
    """After the joint refit an accepted effect whose size is within its error is no finding: it
    leaves the accepted list and the final model; a significant one stays, with its values."""
    from types import SimpleNamespace

    from ssamb.closeloop.search import SearchResult, _drop_null_effects

    load = _amb_model("static_load", {"axes": ["x", "y"]})
    dead = _amb_model("amplifier_deadtime", {})
    # two calibration parameters, then the load (18, -4.6 N +- 0.3 N) and a dead time of 2 +- 10 ns
    theta = np.array([0.01, -0.02, 18.0, -4.6, 2e-9])
    cov = np.diag([1e-4, 1e-4, 0.09, 0.09, 1e-16])
    fit = SimpleNamespace(theta=theta, cov_misfit=cov, se_misfit=np.sqrt(np.diag(cov)))
    out = SearchResult(accepted=[{"name": "static_load", "round": 0}, {"name": "amplifier_deadtime", "round": 1}])
    eff = _drop_null_effects(out, fit, [load, dead], np.array([2, 4, 5]), 1e-3, False)
    assert [a["name"] for a in out.accepted] == ["static_load"]
    assert eff == [{"name": "static_load", "fx_n": 18.0, "fy_n": -4.6}]
    assert out.dropped[0]["name"] == "amplifier_deadtime" and out.dropped[0]["size_chi2"] == pytest.approx(0.04)


@pytest.mark.parametrize("z_zeroed, z_refit, refit_cheaper", [(0.5, None, None), (5.0, 5.0, None),
                                                              (5.0, 1.0, True), (5.0, 1.0, False)])
def test_a_weak_effect_is_weighed_by_the_held_out_part(monkeypatch, z_zeroed, z_refit, refit_cheaper):
    """:func:`ssamb.closeloop.search._weigh_weak`, a load (18, -4.6 +- 0.3 N) and a dead time of
    2 +- 10 ns whose Wald test is weak: when the same model with the dead time at zero predicts the
    held-out part as well (z 0.5 <= 3.09) it goes with no refit; when the zeroed model is worse
    (z 5) and so is the joint refit without it (z 5) it stays (``beyond_z``); when only the zeroed
    model is worse, it goes and the final model is the refit without it if that has the lower
    joint objective (its load, 17.5 and -4.5, and its covariance with a zero row for the dead
    time), the zeroed model otherwise. :func:`_drop_null_effects` then reports what went."""
    from types import SimpleNamespace

    from ssamb.closeloop import search

    from ssamb.closeloop.estimate import MapFit

    def fit_of(theta, var):
        c = np.diag(var)                 # a real MapFit: its standard errors are its covariances' diagonals
        return MapFit(np.array(theta), c, c, np.zeros((0, len(theta))), np.zeros((len(theta),) * 2), 0.0, 0, 0.0,
                      0, 0, True)

    load = _amb_model("static_load", {"axes": ["x", "y"]})
    dead = _amb_model("amplifier_deadtime", {})
    ov, ov_alt = {"with": 1}, {"refit": 1}
    joint = (fit_of([0.01, -0.02, 18.0, -4.6, 2e-9], np.array([1e-4, 1e-4, 0.09, 0.09, 1e-16])), np.zeros(2), ov,
             [], [load, dead], np.array([2, 4, 5]), {})
    alt = (fit_of([0.02, -0.01, 17.5, -4.5], np.array([1e-4, 1e-4, 0.04, 0.04])), np.zeros(2), ov_alt, [], [load],
           np.array([2, 4]), {})
    joints = []

    def refit(cmp, cal, accepted, settings, est, progress, start):
        joints.append([a["name"] for a in accepted])
        return alt
    monkeypatch.setattr(search, "_joint", refit)
    monkeypatch.setattr(search, "improvement_z",
                        lambda cmp, part, base, pred, o, e: z_zeroed if base.overrides is ov else z_refit)
    monkeypatch.setattr(search, "_objectives", lambda cmp, a, b: (2.0, 1.0) if refit_cheaper else (1.0, 2.0))
    cmp = SimpleNamespace(hold="held-out part", prediction=lambda o, e: {})
    out = search.SearchResult(accepted=[{"name": "static_load", "round": 0}, {"name": "amplifier_deadtime",
                                                                               "round": 1}])
    got = search._weigh_weak(cmp, None, out, SimpleNamespace(alpha_accept=1e-3), None, False, np.zeros(2), joint)
    assert joints == ([] if z_zeroed < 3.09 else [["static_load"]])
    eff = search._drop_null_effects(out, got[0], got[4], got[5], 1e-3, False)
    if z_refit is not None and z_refit > 3.09:
        assert [a["name"] for a in out.accepted] == ["static_load", "amplifier_deadtime"] and not out.dropped
        assert out.accepted[1]["beyond_z"] == 5.0
        return
    assert [a["name"] for a in out.accepted] == ["static_load"]
    d = out.dropped[0]
    assert d["name"] == "amplifier_deadtime" and d["theta"]["deadtime_s"] == 2e-9
    assert d["beyond_z"] == z_zeroed and d["refit_z"] == z_refit
    from ssamb.closeloop.report import _dropped_note

    note = _dropped_note(d)
    assert f"z {z_zeroed:.2f} over the same model with it at zero" in note
    assert ("over the joint refit without it" in note) == (z_refit is not None)
    if refit_cheaper:
        assert got[2] is ov_alt and eff == [{"name": "static_load", "fx_n": 17.5, "fy_n": -4.5}]
        assert got[0].cov_misfit.shape == (5, 5) and not got[0].cov_misfit[4].any() and not got[0].cov[:, 4].any()
        assert got[0].se_misfit[:4] == pytest.approx([0.01, 0.01, 0.2, 0.2])
    else:
        assert got[2] is ov and eff == [{"name": "static_load", "fx_n": 18.0, "fy_n": -4.6}]


def test_an_alias_as_plausible_as_the_fit_widens_the_reported_error_not_the_size_test():
    """An accepted effect whose fit had a point as plausible 4 units away on its second parameter
    (alias standard deviation 2): after the joint refit (standard errors 0.3) that parameter is
    reported with sqrt(0.3^2 + 2^2), the other with 0.3; its size is still tested on the joint
    refit's covariance (the alias is a second value, not a doubt that the effect exists)."""
    from types import SimpleNamespace

    from ssamb.closeloop.search import SearchResult, _drop_null_effects

    load = _amb_model("static_load", {"axes": ["x", "y"]})
    cov = np.diag([1e-4, 0.09, 0.09])
    fit = SimpleNamespace(theta=np.array([0.01, 18.0, -4.6]), cov_misfit=cov, se_misfit=np.sqrt(np.diag(cov)))
    out = SearchResult(accepted=[{"name": "static_load", "round": 0, "alias_sd": np.array([0.0, 2.0])}])
    _drop_null_effects(out, fit, [load], np.array([1, 3]), 1e-3, False)
    assert [a["name"] for a in out.accepted] == ["static_load"]
    assert out.accepted[0]["se"] == pytest.approx([0.3, math.sqrt(0.09 + 4.0)])


def _amb_model(name: str, hints: dict):
    """The AMB device's parameterisation of an effect on data exciting both axes."""
    from types import SimpleNamespace

    from ssamb.closeloop.settings import Settings
    from ssamb.device import get_device

    return get_device("amb").effect_model(name, hints, SimpleNamespace(excited_axes=("x", "y")), Settings())


def test_a_parameter_seen_in_one_entry_of_many_is_determined():
    """A parameter that moves one entry of 2000 by 20 noise units per unit (a static load moving a
    view's DC), among entries of unit noise that a second parameter moves diffusely: the row-wise
    analysis determines it (the whole vector's Jacobian noise, sqrt(2N) entries' worth, hides
    it), and its estimate lies within its standard errors of the truth."""
    N = 2000
    rng = np.random.default_rng(4)
    B = np.zeros((N, 2))
    B[7, 0] = 20.0
    B[:, 1] = 3.0 * rng.standard_normal(N) / math.sqrt(N) * 10
    e_data = rng.standard_normal(N)
    truth = np.array([0.8, -0.2])

    def evaluate(theta, seed):
        return B @ (np.asarray(theta) - truth) - e_data + 0.7 * np.random.default_rng(seed).standard_normal(N)

    prob = Problem(("load", "diffuse"), np.zeros(2), np.full(2, np.inf), np.array([0.1, 0.1]), np.full(2, -5.0),
                   np.full(2, 5.0), evaluate, groups=[np.arange(N)], probe=np.zeros(2, bool))
    fit = map_fit(prob, EstimateSettings())
    assert abs(fit.theta[0] - truth[0]) < 3 * fit.se[0] and fit.se[0] < 0.1, (fit.theta, fit.se)
    assert abs(fit.theta[1] - truth[1]) < 3 * fit.se[1], (fit.theta, fit.se)


def test_infeasible_replays_are_steps_too_long_not_costs():
    """A linear problem whose replays 'drop the body' (NaN residual) beyond a wall at a = 0.6 on
    the way to a truth at a = 1.0 from a = 0: the fit never centres beyond the wall, counts the
    infeasible replays, and ends at the feasible side (a costs-as-penalty fit would have jumped
    or stalled far from it)."""
    N = 80
    rng = np.random.default_rng(7)
    col = 20.0 * rng.standard_normal(N) / math.sqrt(N)

    def evaluate(theta, seed):
        if theta[0] > 0.6:
            return np.full(N, np.nan)
        return col * (theta[0] - 1.0) + 0.1 * np.random.default_rng(seed).standard_normal(N)

    prob = Problem(("a",), np.zeros(1), np.array([np.inf]), np.array([0.05]), np.array([-2.0]), np.array([2.0]),
                   evaluate)
    fit = map_fit(prob, EstimateSettings(max_iter=12))
    assert fit.infeasible > 0
    assert 0.4 < fit.theta[0] <= 0.6
    assert all(h["theta"][0] <= 0.6 for h in fit.history if "theta" in h)


def test_a_centre_never_drops_the_body_more_often_than_the_last():
    """Beyond a = 0.5 one replay in four drops the body (seeds divisible by 4), on the way to a
    truth at a = 1.0 from a = 0: the majority of replays there is feasible, but the fit never
    centres where more replays drop than where it stands (a prediction averages replays, and a
    drop is no misfit a lower cost of the others offsets)."""
    N = 80
    col = 20.0 * np.random.default_rng(8).standard_normal(N) / math.sqrt(N)

    def evaluate(theta, seed):
        if theta[0] > 0.5 and seed % 4 == 0:
            return np.full(N, np.nan)
        return col * (theta[0] - 1.0) + 0.1 * np.random.default_rng(seed).standard_normal(N)

    prob = Problem(("a",), np.zeros(1), np.array([np.inf]), np.array([0.05]), np.array([-2.0]), np.array([2.0]),
                   evaluate)
    fit = map_fit(prob, EstimateSettings(max_iter=12, short_iter=0))
    assert fit.infeasible > 0
    assert all(h["theta"][0] <= 0.5 for h in fit.history if "theta" in h)


def test_an_infeasible_start_falls_back_and_a_fit_cut_short_says_so():
    """From an infeasible start the fit starts at its fallback; cut to one iteration with its cost
    far above the noise floor it has stopped short, and says so; given the iterations it
    converges to the truth and has not."""
    N = 60
    col = np.linspace(-30.0, 30.0, N)

    def evaluate(theta, seed):
        if theta[0] < -1.0:
            return np.full(N, np.nan)
        return col * (theta[0] - 3.0) + 0.2 * np.random.default_rng(seed).standard_normal(N)

    def prob():
        return Problem(("a",), np.zeros(1), np.array([np.inf]), np.array([0.1]), np.array([-5.0]), np.array([5.0]),
                       evaluate, start=np.array([-3.0]), fallback=np.array([0.0]))
    short = map_fit(prob(), EstimateSettings(max_iter=1, short_iter=0))
    assert short.infeasible >= 4 and 0.0 <= short.theta[0] < 1.0
    assert short.stopped_short and short.floor_ratio > 2
    full = map_fit(prob(), EstimateSettings(max_iter=12))
    assert full.converged and not full.stopped_short
    assert full.theta[0] == pytest.approx(3.0, abs=0.02)


@pytest.mark.parametrize("common_seeds", [0, 4])
@pytest.mark.parametrize("wall, stage_points", [("axis", 8), ("joint", 16)])
def test_an_infeasible_start_is_searched_for_in_the_prior(wall, stage_points, common_seeds):
    """A start (the prior mean) where every replay drops the body, with no fallback, and a truth
    at (1.5, 1.5) prior standard deviations where the body floats: the body floats only at
    b > 1.2 (one parameter alone at 2 sd finds it) or only at a + b > 2.5 (no parameter alone
    within 2 sd does; the Sobol points over +-2 sd do). The fit starts where the body floats and
    reaches the truth, with the surrogate's Gauss-Newton and with the common-seeds least squares;
    with no floating point in the prior's 2 sd it stays, unmoved, and says so."""
    from ssamb.closeloop.estimate import feasible_start

    N = 60
    rng = np.random.default_rng(11)
    cols = rng.standard_normal((N, 2)) * 10.0

    def floats(theta):
        return theta[1] > 1.2 if wall == "axis" else theta[0] + theta[1] > 2.5

    def evaluate(theta, seed):
        if not floats(theta):
            return np.full(N, np.nan)
        return cols @ (np.asarray(theta) - 1.5) + 0.2 * np.random.default_rng(seed).standard_normal(N)

    def prob(ev=evaluate):
        return Problem(("a", "b"), np.zeros(2), np.ones(2), np.full(2, 0.05), np.full(2, -5.0), np.full(2, 5.0), ev)
    start, tried = feasible_start(prob(), np.zeros(2))
    assert floats(start) and tried == stage_points
    fit = map_fit(prob(), EstimateSettings(max_iter=12, common_seeds=common_seeds))
    assert fit.infeasible >= 4
    assert fit.theta == pytest.approx([1.5, 1.5], abs=0.05)
    never = map_fit(prob(lambda theta, seed: np.full(N, np.nan)), EstimateSettings(max_iter=12,
                                                                                 common_seeds=common_seeds))
    assert np.all(never.theta == 0.0)
    assert never.history == [{"infeasible_start": True}] if not common_seeds else not never.converged


def test_a_candidate_starts_from_its_base_as_it_is_only_when_that_costs_clearly_less():
    """:func:`ssamb.closeloop.fit.better_base_start`: a base parameter b (prior sd 1, mean 0) the
    data put at 0.8 and an effect e started at 1.5. With the base at b = 0.8 the mean residual's
    cost (4 replays) is 0.64 of prior against |c|^2 0.64 = 1.3e4 at the prior mean: the base is
    taken, e keeps its start. Where the data barely see b (c 100 times smaller: 1.3 against the
    base's prior cost 0.64, inside the margin 2 sqrt(12 N / 4) = 26.8 for N = 60) or do not see it
    at all (the base at b = 3 costs its prior's 9 more), the prior-mean start stays."""
    from ssamb.closeloop.fit import better_base_start

    N = 60
    c = np.linspace(-30.0, 30.0, N)
    d = np.cos(np.arange(N))

    def prob(scale, fallback_b):
        def evaluate(theta, seed):
            return scale * c * (theta[0] - 0.8) + d * (theta[1] - 2.0) + np.random.default_rng(seed).standard_normal(N)
        return Problem(("b", "e"), np.zeros(2), np.array([1.0, np.inf]), np.array([0.1, 0.1]), np.full(2, -5.0),
                       np.full(2, 5.0), evaluate, start=np.array([0.0, 1.5]), fallback=np.array([fallback_b, 0.0]))
    msgs: list = []
    assert better_base_start(prob(1.0, 0.8), 1, 4, msgs.append) == pytest.approx([0.8, 1.5])
    assert msgs and msgs[0].startswith("starts from its base as it is")
    assert better_base_start(prob(0.01, 0.8), 1, 4) == pytest.approx([0.0, 1.5])
    assert better_base_start(prob(0.0, 3.0), 1, 4) == pytest.approx([0.0, 1.5])


def test_a_candidate_worse_than_no_effect_is_fitted_again_from_its_base():
    """:func:`ssamb.closeloop.fit._rescued`: a base parameter b the data put at 0.8 (c = 300 per
    unit: far outside its prior sd 1 of information) and an effect e = 2. Started at b = 0 (its
    prior mean) with one iteration the fit stops short far above the base's cost with e = 0
    (about 4 |d|^2 + N = 180); fitted again from the base as it is it ends at (0.8, 2). A fit that
    converged is returned as it is."""
    from ssamb.closeloop.fit import _rescued
    from ssamb.device import EffectModel

    N = 60
    c = 10.0 * np.linspace(-30.0, 30.0, N) / 30.0
    d = np.cos(np.arange(N))

    def evaluate(theta, seed):
        return 30.0 * c * (theta[0] - 0.8) + d * (theta[1] - 2.0) + np.random.default_rng(seed).standard_normal(N)

    def prob():
        return Problem(("b", "e"), np.zeros(2), np.array([1.0, np.inf]), np.array([0.01, 0.1]), np.full(2, -5.0),
                       np.full(2, 5.0), evaluate, start=np.array([0.0, 0.0]), fallback=np.array([0.8, 0.0]))
    model = EffectModel("e", ("e",), np.zeros(1), np.full(1, 0.1), np.full(1, -5.0), np.full(1, 5.0),
                        lambda t: [], {})
    one = EstimateSettings(max_iter=1, short_iter=0)
    p = prob()
    short = map_fit(p, one)
    assert short.stopped_short and short.chi2 > 1e3
    msgs: list = []
    again = _rescued(p, model, short, EstimateSettings(max_iter=6, short_iter=0), 1, msgs.append)
    assert msgs[-1].startswith("worse than no effect") and msgs[-1].endswith(": taken")
    assert again.theta == pytest.approx([0.8, 2.0], abs=0.05)
    p = prob()
    done = map_fit(p, EstimateSettings(max_iter=12))
    assert not done.stopped_short and _rescued(p, model, done, one, 1, None) is done


def test_calibration_agreement_is_a_chi_square_of_the_differences():
    """Two recordings 1.0 +- 0.1 and 1.4 +- 0.1: weighted mean 1.2, chi-square 8 on 1 degree of
    freedom; a session parameter is left out; one identified in a single recording is listed so."""
    from ssamb.closeloop.recordings import calibration_agreement

    def rep(v, ident):
        return {"calibration": {"stopped_short": False, "parameters": [
            {"key": "k", "value": v, "se": 0.1, "identified": ident},
            {"key": "zero", "value": v, "se": 0.1, "identified": True}]}}
    out = calibration_agreement({"a": rep(1.0, True), "b": rep(1.4, False)}, session=("zero",))
    assert set(out) == {"k"}
    assert out["k"]["value"] == pytest.approx(1.2) and out["k"]["chi2"] == pytest.approx(8.0)
    assert out["k"]["dof"] == 1 and out["k"]["p"] == pytest.approx(0.004678, rel=1e-3)
    assert out["k"]["identified_in"] == ["a"]


def test_a_delay_near_a_whole_sample_is_mirrored_across_it():
    """A fitted delay of 0.97 samples is mirrored to 1.03 (the cost's kink at one sample hides
    the other side from a local fit); one in mid-sample or below the first sample is not."""
    from ssamb.sim.effects.sensor_delay import _mirrors

    ts = 36e-6
    out = _mirrors(np.array([0.97 * ts, 0.5 * ts]), ts)
    assert len(out) == 1 and out[0][0] == pytest.approx(1.03 * ts) and out[0][1] == pytest.approx(0.5 * ts)
    assert _mirrors(np.array([0.1 * ts]), ts) == []


def test_a_delay_has_aliases_one_whole_sample_away_on_each_axis():
    """A fitted (x, y) delay of (2.1, 0.4) samples has the aliases (1.1, 0.4), (3.1, 0.4) and
    (2.1, 1.4): none below zero."""
    from ssamb.sim.effects.sensor_delay import _aliases

    ts = 12e-6
    out = np.array(_aliases(np.array([2.1 * ts, 0.4 * ts]), ts)) / ts
    assert out == pytest.approx(np.array([[1.1, 0.4], [3.1, 0.4], [2.1, 1.4]]))


@pytest.mark.parametrize("gap, expect_sd", [(0.0, 0.5), (1.0, 0.5), (40.0, 0.0)])
def test_alias_sd_is_half_the_distance_to_a_point_as_plausible(gap, expect_sd):
    """An effect whose cost has two minima one unit apart: equal ones (the data cannot tell them)
    give a spread of half their distance, and so does one a standard deviation of the averaged
    cost difference higher; one 40 standard deviations higher gives none. Costs are sums of squares of unit-variance
    replay noise about each point's mean misfit, 200 entries, four replays each."""
    from types import SimpleNamespace

    from ssamb.closeloop.fit import _one_replay_margin, alias_sd

    n = 200
    sd = _one_replay_margin(n, 4) / 2.0

    def batch(points):
        out = []
        for theta, seed in points:
            rng = np.random.default_rng(seed)
            off = 0.0 if abs(theta[1] - 0.3) < 0.5 else np.sqrt(gap * sd / n)
            out.append(rng.normal(size=n) + off)
        return out
    prob = SimpleNamespace(batch=batch, seed0=0)
    model = SimpleNamespace(params=("d",), lower=np.array([0.0]), upper=np.array([5.0]), mirrors=None,
                            aliases=lambda t: [t + 1.0])
    fit = SimpleNamespace(theta=np.array([0.3, 0.0]))
    assert alias_sd(prob, model, fit, 1) == pytest.approx([expect_sd])


def test_one_replay_margin_is_two_sd_of_a_cost_difference_at_the_floor():
    """Two replays of one model against one data set (shared data noise, own model noise, unit
    variance each): the spread of the difference of their costs is sqrt(12 n)."""
    from ssamb.closeloop.fit import _one_replay_margin

    rng = np.random.default_rng(3)
    n, trials = 400, 4000
    d = rng.normal(size=(trials, n))
    diff = np.sum((d + rng.normal(size=(trials, n))) ** 2 - (d + rng.normal(size=(trials, n))) ** 2, axis=1)
    assert _one_replay_margin(n) == pytest.approx(2.0 * diff.std(), rel=0.05)


def test_data_implied_limits_narrow_the_bounds_of_a_calibration():
    """A relative parameter (nominal 2, tolerance 10 %) limited to at most 2.1, and an absolute one
    (nominal 0, tolerance 1) to at least -0.5: the problem's bounds in theta units are the prior's
    five tolerances cut at those limits; limits already set are only tightened."""
    from ssamb.closeloop.calibration import bounded, calibration_problem, parameter_specs

    cfg = {"a": {"gain": 2.0, "zero": 0.0}}
    specs = bounded(parameter_specs(cfg, {"a.gain": 0.1, "a.zero": 1.0}),
                    {"a.gain": (None, 2.1), "a.zero": (-0.5, None)})
    p = calibration_problem(specs, None)
    assert p.upper == pytest.approx([0.05, 5.0]) and p.lower == pytest.approx([-0.5, -0.5])
    again = bounded(specs, {"a.gain": (None, 2.5), "a.zero": (-0.2, None)})
    assert again[0].upper == 2.1 and again[1].lower == -0.2
    # an upper limit under the nominal value: five tolerances of room below it, but never past a
    # lower limit the data imply nor a relative parameter's -90 %
    low = calibration_problem(bounded(parameter_specs(cfg, {"a.gain": 0.1, "a.zero": 1.0}),
                                      {"a.gain": (None, 1.0), "a.zero": (-1.5, -1.0)}), None)
    assert low.upper == pytest.approx([-0.5, -1.0]) and low.lower == pytest.approx([-0.9, -1.5])


def _cusp_problem(N: int = 60) -> Problem:
    """A one-parameter problem whose residual has a cusp at 3 (:math:`r = c\\,\\mathrm{sign}(x)
    \\sqrt{|x|}`) plus a misfit of +-8 per entry no parameter explains, noise 0.3 per entry."""
    col = np.linspace(-30.0, 30.0, N)
    off = np.where(np.arange(N) % 2 == 0, 8.0, -8.0)

    def evaluate(theta, seed):
        x = theta[0] - 3.0
        return col * np.sign(x) * np.sqrt(abs(x)) + off + 0.3 * np.random.default_rng(seed).standard_normal(N)
    return Problem(("a",), np.zeros(1), np.array([np.inf]), np.array([0.1]), np.array([-5.0]), np.array([10.0]),
                   evaluate, start=np.array([0.0]))


def test_a_fit_whose_steps_no_longer_lower_the_cost_stops():
    """A residual with a cusp at its optimum (:math:`r = c\\,\\mathrm{sign}(x)\\sqrt{|x|}` plus a
    misfit no parameter explains, far above the noise floor): the Gauss-Newton steps overshoot
    across the cusp and the cost no longer falls. With ``progress_window`` 3 the fit stops once
    three steps lowered the cost by less than its noise, not converged, at a cost within that
    noise of where the whole budget ends (``progress_window`` 0), for fewer replays."""
    from ssamb.closeloop.estimate import _margin

    N = 60
    prob = _cusp_problem
    full = map_fit(prob(), EstimateSettings(progress_window=0))
    cut = map_fit(prob(), EstimateSettings(progress_window=3))
    assert not any(h.get("no_progress") for h in full.history)
    assert any(h.get("no_progress") for h in cut.history) and not cut.converged
    assert cut.evaluations < 0.7 * full.evaluations
    assert abs(cut.chi2 - full.chi2) < _margin(N, 0.09 / 4, full.chi2)
    assert cut.theta[0] == pytest.approx(3.0, abs=0.05)


def test_a_fit_stopped_short_stops_its_extra_iterations_when_they_no_longer_lower_the_cost():
    """The same cusp: with ``short_progress_window`` 3 the fit runs its first ``max_iter``
    iterations exactly as without it, and in the iterations a fit far above the floor is given
    beyond them stops once three steps lowered the cost by less than its noise, for fewer
    replays and at a cost within that noise of where the whole budget ends."""
    from ssamb.closeloop.estimate import _margin

    N = 60
    prob = _cusp_problem
    s = EstimateSettings(max_iter=4, short_iter=12)
    full = map_fit(prob(), s)
    cut = map_fit(prob(), dataclasses.replace(s, short_progress_window=3))
    first = [h for h in full.history if h.get("iteration", 99) < s.max_iter]
    assert [h for h in cut.history if h.get("iteration", 99) < s.max_iter] == first
    stops = [h["iteration"] for h in cut.history if h.get("no_progress")]
    assert stops and stops[0] >= s.max_iter and not any(h.get("no_progress") for h in full.history)
    assert cut.evaluations < full.evaluations
    assert abs(cut.chi2 - full.chi2) < _margin(N, 0.09 / 4, full.chi2)


def _alias_comparison(monkeypatch, z_hold: dict, z_fit: dict):
    """A comparison whose prediction is the effect's delay and whose improvement z of a delay
    over the final model is read from ``z_hold`` (held-out part) and ``z_fit`` (fitting part):
    the alias checks of :mod:`ssamb.closeloop.search` without replays."""
    from ssamb.closeloop import search

    class Cmp:
        hold = "held-out part"
        fit = "fitting part"

        def prediction(self, overrides, effects):
            return {"delay": effects[0]["delay"]}

    monkeypatch.setattr(search, "improvement_z", lambda cmp, part, base, pred, ov, eff:
                        (z_hold if part == Cmp.hold else z_fit)[pred["delay"]])
    return Cmp


def test_an_alias_replaces_a_fit_only_when_the_held_out_part_prefers_it_significantly(monkeypatch):
    """:func:`ssamb.closeloop.search._better_alias` (the final model's and every candidate's alias
    check): of the aliases whose held-out improvement over the fit exceeds the critical z and that
    the fitting part prefers too, the one with the largest; none when every alias stays below it,
    however close, or the fitting part prefers the fit; aliases outside the effect's bounds are
    clipped to them before they are replayed."""
    from types import SimpleNamespace

    from ssamb.closeloop import search

    z_of = {12.0: 5.0, -12.0: 7.0, 24.0: 3.0}          # held-out z of each alias over the fit at 0
    z_fit = {12.0: 1.0, -12.0: 0.5, 24.0: 1.0}         # the same on the fitting part

    Cmp = _alias_comparison(monkeypatch, z_of, z_fit)
    model = SimpleNamespace(lower=np.array([-12.0]), upper=np.array([24.0]),
                            aliases=lambda t: [t + 12.0, t - 12.0, t - 30.0])
    build = lambda t: [{"delay": float(t[0])}]                     # noqa: E731
    best = search._better_alias(Cmp(), {}, [], {}, model, np.array([0.0]), build, z_crit=3.09)
    assert best[0] == 7.0 and best[1] == pytest.approx([-12.0]) and best[2] == [{"delay": -12.0}]
    z_fit[-12.0] = -0.5                                 # the fitting part prefers the fit: not that one
    best = search._better_alias(Cmp(), {}, [], {}, model, np.array([0.0]), build, z_crit=3.09)
    assert best[0] == 5.0 and best[1] == pytest.approx([12.0])
    z_of.update({12.0: 3.0, -12.0: 3.08})
    assert search._better_alias(Cmp(), {}, [], {}, model, np.array([0.0]), build, z_crit=3.09) is None
    model.aliases = lambda t: [t + 30.0]                          # clipped to the upper bound, 24
    z_of[24.0] = 4.0
    moved = search._better_alias(Cmp(), {}, [], {}, model, np.array([0.0]), build, z_crit=3.09)
    assert moved[1] == pytest.approx([24.0])


def test_a_delays_spread_over_its_comb_counts_every_point_the_record_does_not_reject(monkeypatch):
    """:func:`ssamb.closeloop.search._alias_spread`: of the comb's points (whole samples away), those
    whose improvement over the final model is above -z_c on both parts are plausible, and the
    spread is the root mean square distance over them and the reported point, equally likely
    (two points d apart: d/sqrt(2)); none plausible: 0."""
    from types import SimpleNamespace

    from ssamb.closeloop import search

    z_hold = {15.0: -5.0, 39.0: -3.7, 51.0: -2.0, 63.0: -3.0, 75.0: -8.0}
    z_fit = {15.0: 0.5, 39.0: 1.0, 51.0: 0.3, 63.0: -3.2, 75.0: 0.0}

    Cmp = _alias_comparison(monkeypatch, z_hold, z_fit)
    model = SimpleNamespace(params=("delay_x_s",), lower=np.array([0.0]), upper=np.array([1e3]),
                            build=lambda t: [{"delay": float(t[0])}],
                            comb=lambda t: [t + k for k in (-12.0, 12.0, 24.0, 36.0, 48.0)])
    a = {"model": model, "theta": np.array([27.0])}
    out = SimpleNamespace(accepted=[a], overrides={}, effects=[{"delay": 27.0}], final={"delay": 27.0})
    s, plausible = search._alias_spread(Cmp(), out, a, 3.09)
    assert [p["delay_x_s"] for p in plausible] == [51.0] and plausible[0]["z_hold"] == -2.0
    assert s[0] == pytest.approx(24.0 / np.sqrt(2.0))
    z_hold[15.0] = -1.0                                  # 12 below too: (12^2 + 24^2) / 3
    s, plausible = search._alias_spread(Cmp(), out, a, 3.09)
    assert s[0] == pytest.approx(np.sqrt((144.0 + 576.0) / 3.0)) and len(plausible) == 2
    z_hold.update({15.0: -4.0, 51.0: -3.1})
    s, plausible = search._alias_spread(Cmp(), out, a, 3.09)
    assert s[0] == 0.0 and plausible == []


def test_the_delay_comb_covers_its_search_range_one_axis_at_a_time():
    """:func:`ssamb.sim.effects.sensor_delay._comb`: every whole controller sample away within
    [0, max(120 us, tau + Ts)], one axis at a time, never the point itself."""
    from ssamb.sim.effects.sensor_delay import _comb

    ts = 12e-6
    pts = _comb(np.array([27e-6, 51e-6]), ts)
    xs = sorted(p[0] for p in pts if p[1] == 51e-6)
    ys = sorted(p[1] for p in pts if p[0] == 27e-6)
    assert len(pts) == len(xs) + len(ys)
    assert np.allclose(xs, [3e-6, 15e-6] + [27e-6 + k * ts for k in range(1, 8)])
    assert np.allclose(ys, [3e-6 + k * ts for k in range(4)] + [51e-6 + k * ts for k in range(1, 6)])
    assert all(p.min() >= 0 and p.max() <= 120e-6 for p in pts)
    assert np.allclose(max(p[0] for p in _comb(np.array([130e-6]), ts)), 142e-6)


def test_common_seeds_least_squares_follows_a_narrow_curved_valley():
    """:func:`ssamb.closeloop.estimate.common_seeds_fit`: a residual whose cost lies in a narrow
    curved valley (Rosenbrock's, :math:`r = [20 (x_2 - x_1^2),\\ 1 - x_1]`, minimum at (1, 1)) with
    seeded noise, infeasible (NaN) for :math:`x_1 < -1.6`, started at (-1.2, 1) beside that region:
    the least squares of the mean of 8 replays on common seeds ends at the minimum, within the
    noise's share of it, and the fresh seeds keep it."""
    from ssamb.closeloop.estimate import common_seeds_fit, drops_and_cost

    def evaluate(theta, seed):
        x1, x2 = theta
        if x1 < -1.6:
            return np.full(2, np.nan)
        return np.array([20.0 * (x2 - x1 ** 2), 1.0 - x1]) + 0.05 * np.random.default_rng(seed).standard_normal(2)

    prob = Problem(("x1", "x2"), np.zeros(2), np.array([100.0, 100.0]), np.array([0.1, 0.1]),
                   np.array([-3.0, -3.0]), np.array([3.0, 3.0]), evaluate, start=np.array([-1.2, 1.0]))
    s = EstimateSettings(common_seeds=8)
    th = common_seeds_fit(prob, s).theta
    assert th == pytest.approx([1.0, 1.0], abs=0.05)
    assert drops_and_cost([evaluate(th, 5 + j) for j in range(8)])[1] < 0.1


def test_common_seeds_solution_judged_on_fresh_seeds():
    """A least-squares solution fitted to its own seeds' realisation (here the common seeds carry an
    offset the others lack: the sample average's minimum lies 3 away from the problem's) is
    worse on fresh seeds than the start at the true minimum, and the start is kept."""
    from ssamb.closeloop.estimate import common_seeds_fit

    def evaluate(theta, seed):
        bias = 3.0 if 800_000 <= seed - 1 < 850_000 else 0.0
        return np.array([theta[0] - 1.0 + bias]) + 0.01 * np.random.default_rng(seed).standard_normal(1)

    prob = Problem(("a",), np.zeros(1), np.array([100.0]), np.array([0.1]), np.array([-10.0]), np.array([10.0]),
                   evaluate, start=np.array([1.0]))
    assert common_seeds_fit(prob, EstimateSettings(common_seeds=4)).theta == pytest.approx([1.0])
    prob.evaluate = lambda theta, seed: evaluate(theta, 0)        # no such offset: the solution is kept
    prob.start = np.array([0.0])
    assert common_seeds_fit(prob, EstimateSettings(common_seeds=4)).theta == pytest.approx([1.0], abs=0.01)


def _passing(name: str, value: float):
    """A candidate that passed, as :func:`ssamb.closeloop.search.champion` reads it: its model's
    name and parameter, its fit's values, its prediction (here its name)."""
    from types import SimpleNamespace

    return SimpleNamespace(names=(name,), model=SimpleNamespace(name=name, params=("size",)),
                           fit=SimpleNamespace(theta=np.array([0.1, value]), se=np.array([0.01, value / 10])),
                           n_free=1, overrides={}, effects=[], pred={"name": name}, passed=True, score={})


@pytest.mark.parametrize("z_table, choice, rivals", [
    ({}, "sensor_delay", ["eddy_current"]),                                   # alike: both named
    ({("sensor_delay", "eddy_current"): 6.0}, "eddy_current", []),          # eddy beats the delay
    ({("sensor_delay", "eddy_current"): 3.0}, "sensor_delay", ["eddy_current"]),   # not significantly
    ({("eddy_current", "sensor_delay"): 6.0, ("sensor_delay", "eddy_current"): -6.0}, "sensor_delay", []),
])
def test_the_champion_of_a_round_and_its_rivals(monkeypatch, z_table, choice, rivals):
    """:func:`ssamb.closeloop.search.champion`: starting from the candidate with the largest share
    explained, a passing candidate that predicts the held-out part better by more than z_c (3.09)
    replaces it; every other passing one the choice does not beat by more than z_c is a rival,
    with the choice's z over it. ``z_table[(a, b)]``: how much better b predicts than a (0 when
    absent)."""
    from types import SimpleNamespace

    from ssamb.closeloop import search

    monkeypatch.setattr(search, "improvement_z",
                        lambda cmp, part, base, pred, ov, eff: z_table.get((base.pred["name"], pred["name"]), 0.0))
    delay, eddy = _passing("sensor_delay", 5.7e-3), _passing("eddy_current", 5.2e-3)
    cmp = SimpleNamespace(hold="held-out part")
    base = search.Base({}, [], {})
    got, riv = search.champion(cmp, base, [delay, eddy], delay, SimpleNamespace(alpha_accept=1e-3))
    assert got.model.name == choice
    assert [r["name"] for r in riv] == rivals
    for r in riv:
        assert r["params"] == {"size": 5.2e-3} and r["z"] == z_table.get(("eddy_current", "sensor_delay"), 0.0)
        assert r["uncertainty"] == {"size": pytest.approx(5.2e-4)}


def test_the_effects_a_static_load_can_be_are_fitted_beside_it(monkeypatch):
    """:func:`ssamb.closeloop.search._alias_candidates`: once a static load passes, the cross
    coupling that gives the same force at rest (the AMB's ``ALIASES``, either way round) is fitted
    and judged in the same round unless it was tried there already or is in the base; one that
    passed already is reused, not refitted; an effect without aliases fits nothing more."""
    from types import SimpleNamespace

    from ssamb.closeloop import search
    from ssamb.device import get_device

    amb = get_device("amb")
    assert amb.aliases("static_load") == ("cross_coupling",)
    assert amb.aliases("cross_coupling") == ("static_load",)
    assert amb.aliases("sensor_delay") == ()
    fitted = []

    def fake_try(cmp, base, names, *args, **kw):
        fitted.append(names[0])
        return _passing(names[0], 0.09)
    monkeypatch.setattr(search, "_try", fake_try)
    monkeypatch.setattr(search, "_entry", lambda cand, rnd, settings: {"name": cand.names[0]})
    cmp = SimpleNamespace(device=amb, record=None)
    load = _passing("static_load", 7.0)

    def aliases(best, passing, tried=(), taken=()):
        info = {"candidates": [{"name": n} for n in tried]}
        b = search.Base({}, [{"name": n} for n in taken], {})
        return search._alias_candidates(cmp, b, best, passing, {}, None, info, None, None, 0, False, False)
    got = aliases(load, [load])
    assert fitted == ["cross_coupling"] and [c.model.name for c in got] == ["cross_coupling"]
    fitted.clear()
    assert aliases(load, [load], tried=["cross_coupling"]) == [] and fitted == []
    assert aliases(load, [load], taken=["cross_coupling"]) == [] and fitted == []
    twin = _passing("cross_coupling", 0.1)
    assert aliases(load, [load, twin], tried=["cross_coupling"]) == [twin] and fitted == []
    assert aliases(_passing("sensor_delay", 1e-5), [load]) == [] and fitted == []


@pytest.mark.parametrize("z_nested, explained, passes", [(1.0, 0.5, False), (5.0, 0.5, True), (5.0, 0.04, False)])
def test_a_candidate_must_beat_the_parameters_refitted_alone(monkeypatch, z_nested, explained, passes):
    """:func:`ssamb.closeloop.search._judge_nested`: a candidate that passed against the base is
    judged again against the model nested in it (the parameters refitted alone with its freedom,
    :func:`ssamb.closeloop.search.parameters_only`); without a significant held-out improvement
    over that one (z 1.0), or explaining less than ``min_explained`` of the excess it leaves (4 %
    of it at z 5.0), it is rejected with the reason; with both it passes; the scores are kept."""
    from types import SimpleNamespace

    from ssamb.closeloop import search

    null = SimpleNamespace(fit=object(), overrides={"null": 1}, effects=[], pred={"name": "parameters only"})
    seen = {}

    def score(cmp, base, pred, ov, eff, n, settings):
        seen["base"] = base
        return {"z": z_nested, "z_group": z_nested, "group": "u:dc", "explained": explained, "n_groups": 12}
    monkeypatch.setattr(search, "parameters_only", lambda *a, **k: null)
    monkeypatch.setattr(search, "holdout_score", score)
    monkeypatch.setattr(search, "improvement_z", lambda *a, **k: 25.0)
    cand = _passing("resistance_drift", 0.011)
    cand.reasons, cand.score = [], {"z": 18.8}
    search._judge_nested(SimpleNamespace(hold="held-out part"), search.Base({}, [], {}), cand, None, 0,
                         SimpleNamespace(alpha_accept=1e-3, min_explained=0.2), None)
    assert seen["base"].overrides is null.overrides
    assert cand.score["nested"]["z"] == z_nested and cand.score["nested"]["parameters_only_z"] == 25.0
    assert (not cand.reasons) == passes
    if z_nested < 3.09:
        assert "no significant held-out improvement over the parameters refitted alone" in cand.reasons[0]
    elif not passes:
        assert cand.reasons == ["explains 4 % of the residual excess the parameters refitted alone with the same "
                                "freedom leave (< 20 %)"]


@pytest.mark.parametrize("moved_cheaper", [True, False])
def test_the_parameters_refitted_alone_from_two_starts(monkeypatch, moved_cheaper):
    """:func:`ssamb.closeloop.search.parameters_only`: the base's parameters refitted alone (the
    empty effect) from the candidate's start and from the candidate's end; of the two fits the one
    with the lower fitting-part chi-square plus prior term is kept (the held-out part never
    chooses)."""
    from types import SimpleNamespace

    from ssamb.closeloop import search

    starts = []

    def refit(cmp, base, models, est, seed0, step_rel, log):
        assert [m.params for m in models] == [()] and models[0].build(np.zeros(0)) == []
        starts.append(np.asarray(base.theta_free).copy())
        theta = base.theta_free + 0.01
        return SimpleNamespace(fit=SimpleNamespace(theta=theta), overrides={"start": float(base.theta_free[0])},
                               effects=[], pred={})
    monkeypatch.setattr(search, "fit_candidate", refit)
    # the first fit's residual costs 10 against the second's 4 (or the reverse)
    monkeypatch.setattr(search, "_scaled", lambda cmp, part, b, pred, ov, eff:
                        (np.full(1, np.sqrt(10.0)), np.full(1, 2.0)) if moved_cheaper
                        else (np.full(1, 2.0), np.full(1, np.sqrt(10.0))))
    spec = SimpleNamespace(prior_sd=0.5)
    base = search.Base({}, [], {}, [spec], np.array([0.0]))
    cand = SimpleNamespace(n_free=1, fit=SimpleNamespace(theta=np.array([0.3, 5e-3])))
    got = search.parameters_only(SimpleNamespace(fit="fitting part"), base, cand, None, 7,
                                 SimpleNamespace(calibration_step_rel=0.05))
    assert [s.tolist() for s in starts] == [[0.0], [0.3]]
    assert got.overrides == {"start": 0.3 if moved_cheaper else 0.0}


@pytest.mark.parametrize("delay_reason, retried, load_share", [
    ("explains -13 % of the residual excess (< 20 %)", True, 0.6),
    ("held-out improvement not significant (z = 1.00 <= 3.09; in u_y:lines 1.00 <= 3.92)", False, 0.6),
    ("held-out improvement not significant (z = 1.00 <= 3.09; in u_y:lines 1.00 <= 3.92)", True, 0.95)])
def test_an_effect_hidden_by_a_larger_one_is_tried_again_beside_it(monkeypatch, delay_reason, retried, load_share):
    """:func:`ssamb.closeloop.search._effect_search`, scripted: round 0 fits every effect (no
    signature names one); a load passes, a delay improves the held-out part significantly but
    fails by the share of the excess it explains beside the load's misfit. Round 1, on the base
    with the load, fits the delay again (and it passes there); a delay rejected as not
    significant is not fitted again. A load that explains at least ``sufficient_share`` (0.9) of
    the excess ends round 0 before the delay is fitted: the delay is fitted first in round 1,
    beside the load, whatever it would have scored against the residual the load dominates."""
    from types import SimpleNamespace

    from ssamb.closeloop import search as S
    from ssamb.closeloop.fit import Candidate
    from ssamb.closeloop.settings import Settings

    settings = Settings()
    ev = {n: SimpleNamespace(log10_p=0.0, hints={}, to_json=lambda: {}) for n in ("static_load", "sensor_delay")}
    lib = {n: SimpleNamespace(NEEDS_HINT=False) for n in ev}
    cmp = SimpleNamespace(record=None, device=SimpleNamespace(effects=lib, aliases=lambda n: ()))
    fitted = []

    class FakeBase:
        def __init__(self, effects):
            self.effects, self.shown, self.spare, self.free = effects, None, [], []

        def after(self, cand):
            return FakeBase(self.effects + [{"name": n} for n in cand.names])

    def fake_try(cmp, base, names, *a, **k):
        rnd = len(base.effects)
        fitted.append((rnd, names[0]))
        z = 40.0 if names[0] == "sensor_delay" and delay_reason.startswith("explains") else 1.0
        reasons = [] if names[0] == "static_load" or rnd == 1 else [delay_reason]
        model = SimpleNamespace(name=names[0], params=["p"])
        fit = SimpleNamespace(theta=np.array([1.0]), se=np.array([0.1]))
        share = load_share if names[0] == "static_load" else 0.9
        return Candidate(tuple(names), [model], model, fit, [{"name": names[0]}], {}, {"z": z, "z_group": z,
                         "n_groups": 1, "explained": share, "delta_chi2": 1.0}, reasons)

    monkeypatch.setattr(S, "_round", lambda cmp, base, settings, rnd, rejected: (
        {"round": rnd, "ranking": [], "candidates": []}, [], None, ev))
    monkeypatch.setattr(S, "consistency", lambda cmp, base, settings: (len(base.effects) == 2, []))
    monkeypatch.setattr(S, "_try", fake_try)
    monkeypatch.setattr(S, "_entry", lambda cand, rnd, settings: {"name": "+".join(cand.names)})
    out = S.SearchResult()
    S._effect_search(cmp, FakeBase([]), settings, None, out, False, False)
    assert (1, "sensor_delay") in fitted if retried else (1, "sensor_delay") not in fitted
    assert ((0, "sensor_delay") in fitted) == (load_share < settings.sufficient_share)
    assert [a["name"] for a in out.accepted] == (["static_load", "sensor_delay"] if retried else ["static_load"])


def test_the_held_out_z_counts_the_predictions_own_noise():
    """:func:`ssamb.closeloop.fit.improvement_z` between two equally good models whose replays are
    independent (a chaotic loop: each replay's noise twice the data's), both misfitting (the
    misfit four times the data's noise variance): over 300 data sets its standard deviation is at
    most about one (the jackknife over the paired replays), where the data's noise alone in the
    denominator makes it about two."""
    from types import SimpleNamespace

    from ssamb.closeloop.fit import Base, improvement_z

    rng = np.random.default_rng(7)
    n, m, sigma = 200, 8, 2.0
    misfit = 2.0 * rng.standard_normal(n)
    z_new, z_old = [], []
    for _ in range(300):
        e = rng.standard_normal(n)
        runs = {k: [{"v": e + misfit + sigma * rng.standard_normal(n), "delevitated": False} for _ in range(m)]
                for k in (0, 1)}
        cmp = SimpleNamespace(seeds=tuple(range(m)), device=SimpleNamespace(channels=("v",)),
                              replay=SimpleNamespace(runs=lambda eff, nn, ov, seeds: runs[ov["k"]]),
                              residual=lambda part, pred: pred["v"], noise_factors=lambda part, ov, eff: np.ones(n),
                              memoised=lambda kind, part, ov, eff, compute: compute())
        pred = {k: {"v": np.mean([r["v"] for r in runs[k]], axis=0)} for k in (0, 1)}
        z_new.append(improvement_z(cmp, None, Base({"k": 0}, [], pred[0]), pred[1], {"k": 1}, []))
        r0, r1 = pred[0]["v"], pred[1]["v"]
        z_old.append((r0 @ r0 - r1 @ r1) / (2 * np.linalg.norm(r1 - r0)))
    assert 0.6 < np.std(z_new) < 1.15, (np.std(z_new), np.std(z_old))
    assert abs(np.mean(z_new)) < 0.25
    assert np.std(z_old) > 1.5, (np.std(z_new), np.std(z_old))


@settings(max_examples=25, deadline=None)
@given(m=st.integers(3, 9), seed=st.integers(0, 2**31 - 1), scale=st.floats(1e-9, 1e3))
def test_a_leave_one_out_prediction_is_the_mean_of_the_other_replays(m, seed, scale):
    """:func:`ssamb.closeloop.fit._leave_one_out`: row j is the residual of the mean of every replay
    but the j-th (to round-off), with those replays as its ``runs``; fewer than three replays:
    None."""
    from types import SimpleNamespace

    from ssamb.closeloop.fit import _leave_one_out

    rng = np.random.default_rng(seed)
    runs = [{"a": scale * rng.standard_normal(50), "b": rng.standard_normal(50) + 1e3, "delevitated": i == 1}
            for i in range(m)]
    seen = []

    def residual(part, pred):
        seen.append(pred)
        return np.concatenate([pred["a"], pred["b"]])
    cmp = SimpleNamespace(seeds=tuple(range(m)), device=SimpleNamespace(channels=("a", "b")),
                          replay=SimpleNamespace(runs=lambda eff, nn, ov, seeds: runs[: len(seeds)]), residual=residual)
    rows = _leave_one_out(cmp, None, {}, [])
    for j, (row, pred) in enumerate(zip(rows, seen)):
        others = [r for i, r in enumerate(runs) if i != j]
        want = np.concatenate([np.mean([r[c] for r in others], axis=0) for c in ("a", "b")])
        np.testing.assert_allclose(row, want, rtol=1e-12, atol=1e-12 * scale)
        assert len(pred["runs"]) == m - 1 and pred["delevitated"] == (j != 1 and m > 1)
    cmp.seeds = (0, 1)
    assert _leave_one_out(cmp, None, {}, []) is None


@pytest.mark.parametrize("stopped_short, depth, start_excess, refitted",
                         [(True, 40.0, 1e4, True), (False, 40.0, 1e4, False), (True, 0.5, 1e4, False),
                          (True, 40.0, 1.5, False)])
def test_a_fit_stopped_short_is_refitted_from_the_grid_scored_at_its_parameters(monkeypatch, stopped_short, depth,
                                                                              start_excess, refitted):
    """An effect parameter d with basins at 0.2 and 0.8, scored with the other parameter at the
    fit's value: a fit that stopped short far above the floor in the basin at 0.8 is refitted from
    the grid point 0.2 when that one beats it by ``depth`` standard deviations of a one-replay cost
    difference (40: refitted; half of one: not); a fit that did not stop short is kept as it is, and
    so is one that removed less than half of its start's excess (``start_excess`` times its own:
    1.5, a third removed)."""
    from types import SimpleNamespace

    from ssamb.closeloop import fit as fitmod

    n = 300
    sd = fitmod._one_replay_margin(n) / 2.0

    def mean_cost(theta):                   # the excess cost over the noise floor at theta
        return (0.0 if abs(theta[1] - 0.2) < 0.1 else depth * sd) + 100.0 * (theta[0] - 1.0) ** 2

    def batch(points):
        return [np.random.default_rng(seed).normal(size=n) + np.sqrt(mean_cost(t) / n) for t, seed in points]

    starts = []

    def local_fit(prob, settings, log):     # a local fit ends where it starts
        starts.append(np.array(prob.start))
        return SimpleNamespace(theta=np.array(prob.start), chi2=n + mean_cost(prob.start), stopped_short=False)

    monkeypatch.setattr(fitmod, "map_fit", local_fit)
    prob = SimpleNamespace(batch=batch, seed0=5, lower=np.array([0.0, 0.0]), upper=np.array([2.0, 1.0]),
                           start=np.array([0.0, 0.5]))
    model = SimpleNamespace(params=("d",), grid=(np.array([0.2]), np.array([0.5]), np.array([0.8])))
    fit = SimpleNamespace(theta=np.array([1.0, 0.8]), chi2=n + depth * sd, stopped_short=stopped_short, floor=n,
                          history=[{"probe": ["d"]}, {"iteration": 0, "chi2": n + start_excess * depth * sd}])
    out = fitmod._regridded(prob, model, fit, None, 1, None)
    if refitted:
        assert len(starts) == 1 and starts[0] == pytest.approx([1.0, 0.2])
        assert out.theta == pytest.approx([1.0, 0.2])
    else:
        assert not starts and out is fit


def test_a_comparison_keeps_what_it_reads_off_a_models_replays_while_its_part_stays_the_same():
    """:meth:`Comparison.memoised`: the same kind, part and model give the kept value without
    computing it again; another model, or the part's whitener replaced (new lines, a new noise
    calibration), computes it anew."""
    from types import SimpleNamespace

    from ssamb.closeloop.comparison import Comparison

    cmp = Comparison.__new__(Comparison)
    cmp._memo, cmp.seeds = {}, (1, 2, 3)
    part = SimpleNamespace(layout=object(), data=object(), whitener=object())
    calls = []

    def compute():
        calls.append(1)
        return len(calls)
    ov, eff = {"table1.mass_kg": 1.0}, [{"name": "static_load", "fx_n": 2.0, "fy_n": 0.0}]
    assert cmp.memoised("k", part, ov, eff, compute) == 1
    assert cmp.memoised("k", part, dict(ov), [dict(eff[0])], compute) == 1
    assert cmp.memoised("k", part, {"table1.mass_kg": 1.5}, eff, compute) == 2
    part.whitener = object()
    assert cmp.memoised("k", part, ov, eff, compute) == 3
    assert len(calls) == 3


def _moving_problem(offset: float):
    """:math:`r = c\\,\\mathrm{sign}(x)\\,x^2`, :math:`x = a - 3`, plus an alternating misfit of
    size ``offset`` no parameter explains. A Gauss-Newton step halves :math:`x` (removing 15/16 of
    the cost's excess over the floor when the misfit is 0) once the trust region, which limits the
    first steps from the start at :math:`x = -3`, allows it."""
    N = 60
    col = np.linspace(-30.0, 30.0, N)
    off = np.where(np.arange(N) % 2 == 0, offset, -offset)

    def evaluate(theta, seed):
        x = theta[0] - 3.0
        return col * np.sign(x) * x * x + off + 0.2 * np.random.default_rng(seed).standard_normal(N)
    return Problem(("a",), np.zeros(1), np.array([np.inf]), np.array([0.5]), np.array([-5.0]), np.array([10.0]),
                   evaluate, start=np.array([0.0]))


def test_a_fit_still_on_its_way_goes_on_and_one_beside_a_misfit_does_not():
    """Limited to 2 iterations, a fit whose steps each remove most of its cost's excess and still
    ask for many posterior standard deviations stops short, far from its optimum; with
    ``moving_iter`` 4 it goes on to within 0.2 of it, at a cost near the floor. Beside a misfit
    that dominates the cost, the same steps remove little of the excess: it stops where it
    would have without ``moving_iter``."""
    cut = map_fit(_moving_problem(0.0), EstimateSettings(max_iter=2, short_iter=0, moving_iter=0))
    on = map_fit(_moving_problem(0.0), EstimateSettings(max_iter=2, short_iter=0, moving_iter=4))
    assert cut.stopped_short and abs(cut.theta[0] - 3.0) > 0.8
    its = [h for h in on.history if "step_norm" in h]
    assert 2 < len(its) <= 6 and not on.stopped_short
    assert abs(on.theta[0] - 3.0) < 0.2 and its[-1]["chi2"] < 0.01 * its[1]["chi2"]
    beside = [map_fit(_moving_problem(300.0), EstimateSettings(max_iter=2, short_iter=0, moving_iter=m))
              for m in (0, 4)]
    assert beside[0].theta[0] == beside[1].theta[0] and beside[0].evaluations == beside[1].evaluations
    assert len([h for h in beside[1].history if "step_norm" in h]) == 2


def test_the_share_of_the_excess_is_a_ratio_of_sums():
    """The share a model removes of the excess over the noise: all of it, half of two groups'
    alike, none without excess; a group just above the noise that the model's noise makes worse
    by 22 units moves the share of a 1904-unit excess removed whole by 2 % (its own share, -114 %,
    would take a mean of the groups' shares to -7 %)."""
    from ssamb.closeloop.fit import excess_share

    assert excess_share([(101.0, 1.0, 1)]) == pytest.approx(1.0)
    assert excess_share([(60.0, 40.0, 20), (220.0, 120.0, 20)]) == pytest.approx(0.5)
    assert excess_share([]) == 0.0
    groups = [(1905.4, 0.2, 1), (35.6, 57.9, 16)]
    assert excess_share(groups) == pytest.approx((1905.2 - 22.3) / (1904.4 + 19.6))
    assert np.mean([(x0 - x1) / (x0 - n) for x0, x1, n in groups]) < 0


def test_the_mean_share_gives_every_group_a_vote():
    """As a mean of the groups' own shares, a model that removes one group's excess whole and
    nothing of three others explains a quarter; as a ratio of sums, what that group holds."""
    from ssamb.closeloop.fit import excess_share

    groups = [(1000.0, 0.0, 0)] + [(50.0, 50.0, 10)] * 3
    assert excess_share(groups, "mean") == pytest.approx(0.25)
    assert excess_share(groups, "sum") == pytest.approx(1000.0 / 1120.0)


def test_a_delay_restarts_from_the_slope_its_residual_still_shows():
    """A fitted (x, y) delay of (17, 30.7) us whose residual still shows 13.9 us on x (significant)
    and 2 us on y (not significant) restarts at (30.9, 30.7) us; a residual slope that would give a
    negative delay restarts at zero; no significant axis: no restart."""
    from ssamb.sim.effects.sensor_delay import _restart

    th = np.array([17e-6, 30.7e-6])
    out = _restart(th, {"axes": ["x"], "delay_x": 13.9e-6, "delay_y": 2e-6}, axes=("x", "y"))
    assert out == pytest.approx([30.9e-6, 30.7e-6])
    assert _restart(th, {"axes": ["y"], "delay_y": -40e-6}, axes=("x", "y")) == pytest.approx([17e-6, 0.0])
    assert _restart(th, {"axes": [], "delay_x": 13.9e-6}, axes=("x", "y")) is None


def test_a_gain_restarts_from_the_ratio_its_residual_still_shows():
    """A fitted x gain of 0.9 (parameter -0.1) whose residual still shows a ratio of 0.95 restarts
    at 0.855 (parameter -0.145): gains multiply."""
    from ssamb.sim.effects.sensor_gain import _restart

    out = _restart(np.array([-0.1]), {"axes": ["x"], "gain_x": 0.95}, axes=("x",))
    assert out == pytest.approx([0.9 * 0.95 - 1.0])
    assert _restart(np.array([-0.1]), {"axes": ["y"], "gain_y": 0.95}, axes=("x",)) is None


@pytest.mark.parametrize("z, left_fit, left_restart, taken", [
    (5.0, 10.0, 100.0, True),      # the fitting part prefers the restart significantly
    (-5.0, 100.0, 1.0, False),     # ... or the fit
    (1.0, 133.0, 4.0, True),       # a tie on the fitting part: the one leaving less of its signature
    (-1.0, 4.0, 133.0, False),
])
def test_a_restart_is_preferred_by_the_fitting_part_then_by_its_signature(monkeypatch, z, left_fit, left_restart,
                                                                           taken):
    """:func:`ssamb.closeloop.search._preferred`: the fitting part's improvement z of the restart
    over the fit decides beyond the acceptance level; within it, the smaller sum of the effects'
    claim statistics after their fits."""
    from types import SimpleNamespace

    from ssamb.closeloop import search

    monkeypatch.setattr(search, "improvement_z", lambda *a, **k: z)
    fit = SimpleNamespace(names=("sensor_delay",), score={"claims": {"sensor_delay": (15.9, left_fit)}},
                          overrides={}, effects=[], pred={})
    alt = SimpleNamespace(names=("sensor_delay",), score={"claims": {"sensor_delay": (15.9, left_restart)}},
                          overrides={}, effects=[], pred={})
    base = SimpleNamespace(effects=[])
    cmp = SimpleNamespace(fit="fit")
    got = search._preferred(cmp, base, fit, alt, SimpleNamespace(alpha_accept=1e-3))
    assert got is (alt if taken else fit)


def test_a_signature_left_below_its_own_evidence_threshold_is_not_still_evident():
    """``still_evident`` asks the effect's own evidence test, at the level the search ranks at
    (alpha_evidence shared by the library's effects): a cross-axis test left with p = 0.28 after
    the fit (a chi-square excess of 15.9 over many degrees of freedom) is noise, one left at
    p = 1e-6 with three effects in the library (level 1e-3 / 3) is not."""
    from types import SimpleNamespace

    from ssamb.closeloop.search import still_evident

    seen = []

    def evidence(ft, alpha, st):
        seen.append(alpha)
        return {"significant": ft.p < alpha}
    dev = SimpleNamespace(library=("a", "b", "c"), effects={"a": SimpleNamespace(evidence=evidence)})
    st = SimpleNamespace(alpha_evidence=1e-3)
    assert not still_evident(dev, "a", SimpleNamespace(p=0.28), st)
    assert still_evident(dev, "a", SimpleNamespace(p=1e-6), st)
    assert not still_evident(dev, "a", SimpleNamespace(p=5e-4), st)       # above 1e-3 / 3
    assert seen == [pytest.approx(1e-3 / 3)] * 3


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 5000), buckets=st.integers(1, 300), seed=st.integers(0, 2**31 - 1))
def test_a_plotted_records_envelope_keeps_each_buckets_extremes_in_time_order(n, buckets, seed):
    """:func:`ssamb.closeloop.figures._envelope`: a short record as it is; a long one as at most
    ``buckets`` pairs of samples (buckets of equal length but the last), in time order, holding
    the record's minimum and maximum of every bucket of consecutive samples (so its overall
    range), and nothing that is not a sample."""
    from ssamb.closeloop.figures import _envelope

    rng = np.random.default_rng(seed)
    y = np.cumsum(rng.standard_normal(n))
    t = np.arange(n) / 10.0
    te, ye = _envelope(t, y, buckets)
    if n <= 2 * buckets:
        assert te is t and ye is y
        return
    idx = np.round(te * 10.0).astype(int)
    assert np.all(np.diff(idx) >= 0) and np.array_equal(y[idx], ye)
    assert ye.min() == y.min() and ye.max() == y.max()
    size = -(-n // buckets)
    assert len(ye) == 2 * -(-n // size) and len(ye) <= 2 * buckets
    for a in range(0, n, size):
        inside = ye[(idx >= a) & (idx < a + size)]
        assert inside.min() == y[a:a + size].min() and inside.max() == y[a:a + size].max()


def _periodic_effect(period: float = 1.0, grid_offset: float = 0.1) -> EffectModel:
    """A one-parameter effect ``d`` whose cost has a basin every ``period`` (a delay's cost across
    whole controller samples), with a coarse grid point in every basin."""
    grid = tuple(np.array([k * period + grid_offset]) for k in range(5))
    return EffectModel("toy", ("d",), np.zeros(1), np.array([0.01]), np.zeros(1), np.array([5.0]),
                       lambda t: [], {}, grid)


def test_basin_points_are_the_grid_and_each_parameter_along_it():
    """Two parameters, a grid of three points: the grid's points, then each parameter at every
    value the grid gives it with the other at the fit, less repeats and points within one step
    of the fit in every parameter ((2, 3) beside the fit's (2, 3.05))."""
    m = EffectModel("toy", ("a", "b"), np.zeros(2), np.array([0.1, 0.1]), np.zeros(2), np.full(2, 10.0),
                    lambda t: [], {}, (np.array([1.0, 1.0]), np.array([2.0, 1.0]), np.array([1.0, 3.0])))
    pts = [tuple(p) for p in basin_points(m, np.array([2.0, 3.05]))]
    assert pts == [(1.0, 1.0), (2.0, 1.0), (1.0, 3.0), (1.0, 3.05)]
    assert basin_points(dataclasses.replace(m, grid=()), np.array([2.0, 3.0])) == []


def test_a_joint_fit_far_above_the_floor_is_refitted_from_its_other_basins():
    """A calibrated parameter ``a`` (prior sd 1) and an effect ``d`` whose residual is periodic in
    ``d`` with a slow trend, :math:`r = s\\,\\sin(2\\pi(d - d_0)) v + c (d - d_0) w + B(a - a_0)`:
    a local minimum near every :math:`d_0 + k` whose cost grows with :math:`k^2`. A fit ending
    two basins off stays far above the noise floor; :func:`ssamb.closeloop.search.other_basins`
    refits from the grid's best points and keeps the one in the truth's basin (its cost at the
    floor), and :func:`ssamb.closeloop.search.optimum_of` says so. A fit in the truth's basin is
    returned as it is, without replays."""
    from ssamb.closeloop.search import optimum_of, other_basins

    rng = np.random.default_rng(11)
    n = 240
    v, w, b = (rng.standard_normal(n) / math.sqrt(n) for _ in range(3))
    e_data = 0.5 * rng.standard_normal(n)
    a0, d0 = 0.4, 0.13
    calls = [0]

    def evaluate(theta, seed):
        calls[0] += 1
        a, d = theta
        e_m = 0.5 * np.random.default_rng(seed).standard_normal(n)
        return 40.0 * np.sin(2 * np.pi * (d - d0)) * v + 20.0 * (d - d0) * w + 30.0 * (a - a0) * b + e_data + e_m

    m = _periodic_effect()
    prob = Problem(names=("a", "d"), theta0=np.zeros(2), prior_sd=np.array([1.0, np.inf]), step=np.array([0.05, 0.01]),
                   lower=np.array([-5.0, 0.0]), upper=np.array([5.0, 5.0]), evaluate=evaluate, groups=[np.arange(n)])
    est = EstimateSettings(max_iter=12)
    cuts = np.array([1, 2])
    prob.start = np.array([0.0, 2.1])
    wrong = map_fit(prob, est)
    assert abs(wrong.theta[1] - (d0 + 2)) < 0.1 and wrong.chi2 > 2 * wrong.floor
    fit = other_basins(prob, [m], cuts, wrong, est, 2)
    assert abs(fit.theta[1] - d0) < 0.02 and abs(fit.theta[0] - a0) < 0.05
    assert fit.chi2 < 1.3 * fit.floor
    basins = optimum_of(fit, 1.0)["other_basins"]
    assert basins["taken"] is not None and basins["tried"][basins["taken"]]["cost"] < basins["from_cost"]
    assert "another basin" in optimum_of(fit, 1.0)["how"]
    before = calls[0]
    assert other_basins(prob, [m], cuts, fit, est, 2) is fit and calls[0] == before


@pytest.mark.parametrize("axes", [["x"], ["y"], []])
def test_a_static_load_is_fitted_on_both_axes_whatever_its_evidence(axes):
    """The static load's parameterisation has both forces whichever axes its evidence named (the
    calibrated parameters can hide a load's offset on one axis), and builds the load it is given."""
    from ssamb.sim.effects import static_load

    m = static_load.model({"axes": axes}, None, None)
    assert m.params == ("fx_n", "fy_n")
    assert m.build(np.array([2.0, -3.0])) == [{"name": "static_load", "fx_n": 2.0, "fy_n": -3.0}]


def test_model_averaged_errors_of_an_alternative_as_likely_as_the_choice():
    """One alternative at BIC change 0 (weight 1) three standard errors away, with the same
    variance: the mixture's variance about the estimate is (1 + (1 + 9)) / 2 = 5.5; at a BIC
    change of 100 it barely counts; a parameter it did not refit (NaN) and one it leaves where
    the choice has it with a smaller variance keep the choice's error."""
    from ssamb.closeloop.estimate import model_averaged_sd

    theta, var = np.zeros(3), np.array([1.0, 4.0, 1.0])
    alt = (np.array([3.0, np.nan, 0.0]), np.array([1.0, np.nan, 0.25]), 0.0)
    sd, w = model_averaged_sd(theta, var, [alt])
    assert w.tolist() == [1.0]
    assert sd == pytest.approx([math.sqrt(5.5), 2.0, 1.0])
    far = model_averaged_sd(theta, var, [(alt[0], alt[1], 100.0)])[0]
    assert far[0] == pytest.approx(math.sqrt((1 + math.exp(-50) * 10) / (1 + math.exp(-50))))
    assert model_averaged_sd(theta, var, [])[0] == pytest.approx(np.sqrt(var))


@given(st.floats(-5, 5), st.floats(0.01, 10), st.floats(-20, 40), st.floats(0, 3))
@settings(max_examples=60, deadline=None)
def test_model_averaged_errors_never_shrink_and_grow_with_the_shift(shift, var_c, dbic, extra):
    """Property: the averaged error is never below the chosen model's, and grows with the
    distance of the alternative's estimate."""
    from ssamb.closeloop.estimate import model_averaged_sd

    a = model_averaged_sd(np.zeros(1), np.ones(1), [(np.array([shift]), np.array([var_c]), dbic)])[0][0]
    b = model_averaged_sd(np.zeros(1), np.ones(1), [(np.array([abs(shift) + extra]), np.array([var_c]), dbic)])[0][0]
    assert a >= 1.0 - 1e-12 and b >= a - 1e-12


def test_averaged_errors_widen_what_a_rejected_candidate_moves_and_name_it():
    """:func:`ssamb.closeloop.search.averaged_errors`: a last-round candidate as likely as the
    final model by BIC (its base's misfit 4 per entry divides its change of -8 to -2) that moves
    an offset (absolute, tolerance 1e-5) by 8e-6 against a standard error of 1e-6: the error
    grows beyond a third of the tolerance, the offset is no longer identified and the candidate
    is named; a gain it leaves alone keeps its error; a candidate whose replays drop the body
    does not count; a candidate refined with every parameter free counts once, by its refit."""
    from types import SimpleNamespace as NS

    from ssamb.closeloop.calibration import ParameterSpec
    from ssamb.closeloop import search as S
    from ssamb.closeloop.search import averaged_errors

    specs = [ParameterSpec("offset_m", 0.0, False, 1e-5), ParameterSpec("gain", 1.0, True, 0.03)]
    ident = {"per_parameter": {"offset_m": {"se": 1e-6, "identified": True, "reason": None},
                               "gain": {"se": 0.002, "identified": True, "reason": None}}}

    def cand(dx, drop, keys=("offset_m", "gain")):
        fit = NS(theta=np.array([dx, 0.0, 2e-7][: len(keys)] + [2e-7]), cov=np.diag([1e-12, 4e-6, 1e-14][: len(keys)]
                                                                                     + [1e-14]))
        c = NS(fit=fit, names=("amplifier_deadtime",), pred={"delevitated_share": drop}, n_free=len(keys),
               score={"delta_bic": -8.0, "chi2_fit_before": 4000.0, "n_fit": 1000})
        return S._alternative(c, NS(free=[NS(key=k) for k in keys]))
    assert cand(8e-6, 1.0) is None                  # its replays drop the body: no alternative
    rounds = [{"fits": [cand(8e-6, 0.0)]}]
    out = averaged_errors(ident, specs, np.zeros(2), rounds, 1 / 3)
    off, gain = out["per_parameter"]["offset_m"], out["per_parameter"]["gain"]
    w = math.exp(1.0)
    assert off["se"] == pytest.approx(math.sqrt((1e-12 + w * (1e-12 + 64e-12)) / (1 + w)))
    assert off["se_within_model"] == 1e-6 and not off["identified"] and "amplifier_deadtime" in off["reason"]
    assert gain["se"] == 0.002 and gain["identified"] and "se_within_model" not in gain
    assert out["averaged_over"] == [{"candidate": "amplifier_deadtime", "delta_bic": -2.0, "weight": pytest.approx(w)}]
    assert ident["per_parameter"]["offset_m"]["se"] == 1e-6          # the input is not changed
    assert averaged_errors(ident, specs, np.zeros(2), [{"round": 0, "candidates": []}], 1 / 3) is ident
    refined = averaged_errors(ident, specs, np.zeros(2), [{"fits": [cand(8e-6, 0.0, ("offset_m",)),
                                                                     cand(0.0, 0.0)]}], 1 / 3)
    assert refined["per_parameter"]["offset_m"]["se"] == pytest.approx(1e-6) and len(refined["averaged_over"]) == 1


@pytest.mark.parametrize("x0, x1, z, expect", [
    (300.0, 110.0, 1.0, (300.0, 110.0, 100)),      # above the noise: as it is
    (95.0, 60.0, 4.5, (95.0, 60.0, 60.0)),        # below the noise the data estimate, improved beyond 3.29
    (130.0, 105.0, 4.5, (130.0, 105.0, 100)),     # above its entries, improved: the noise is the entries
    (95.0, 60.0, 3.0, None),                      # improved, not beyond the Bonferroni level over 10 groups
    (120.0, 100.0, 1.0, None),                    # neither
])
def test_a_group_counts_in_the_share_when_above_the_noise_or_significantly_improved(x0, x1, z, expect):
    """:func:`ssamb.closeloop.fit.counted_group`, 100 entries in one of 10 groups: the level of a
    group's improvement is alpha_accept / 10 (z 3.29); above the noise is 2 x the entries or a
    chi-square beyond alpha_noise / 10. A significantly improved group's excess is at least what
    the candidate removed there, and with it the share of the excess is 1."""
    from types import SimpleNamespace

    from ssamb.closeloop.fit import counted_group, excess_share

    s = SimpleNamespace(above_noise=2.0, alpha_noise=1e-3, alpha_accept=1e-3)
    got = counted_group(x0, x1, 100, z, 10, s)
    assert got == expect
    if got is not None and got[2] == x1:
        assert excess_share([got]) == 1.0


@pytest.mark.parametrize("converged, z, reasons, continued", [
    (False, 8.0, ["makes c_y worse"], True),
    (True, 8.0, ["makes c_y worse"], False),                    # a converged fit is where it ends
    (False, 1.0, ["makes c_y worse"], False),                   # no significant improvement to keep
    (False, 8.0, ["makes c_y worse", "BIC does not drop (3.0)"], False),
    (False, 8.0, [], False),                                    # passed
])
def test_a_significant_screen_rejected_for_a_view_it_makes_worse_is_continued(monkeypatch, converged, z, reasons,
                                                                               continued):
    """:func:`ssamb.closeloop.search._continued`: only an unconverged screen that improves the
    held-out part significantly and fails only by views it makes worse is fitted on, from its
    own estimate (the effect's and the refitted parameters'), without the coarse grid."""
    from types import SimpleNamespace

    from ssamb.closeloop import search as S
    from ssamb.closeloop.fit import Base, Candidate
    from ssamb.closeloop.settings import Settings

    calls = []

    def fake_fit(cmp, base, models, est, seed0, step_rel=0.05, log=None, mirror=True, **k):
        calls.append((base.theta_free.tolist(), [m.theta0.tolist() for m in models], mirror))
        return Candidate(("sensor_delay",), models, models[0], SimpleNamespace(converged=True), [])
    monkeypatch.setattr(S, "fit_candidate", fake_fit)
    @dataclasses.dataclass
    class Model:                # the fields of an EffectModel the continuation reads
        name: str
        params: list
        lower: np.ndarray
        upper: np.ndarray
        theta0: np.ndarray
    model = Model("sensor_delay", ["delay_x_s", "delay_y_s"], np.zeros(2), np.full(2, 1e-4), np.zeros(2))
    fit = SimpleNamespace(theta=np.array([0.01, 0.0, 44.7e-6]), converged=converged, iterations=4)
    cand = Candidate(("sensor_delay",), [model], model, fit, [], score={"z": z, "z_group": z, "n_groups": 1},
                     reasons=list(reasons), n_free=1)
    base = Base({}, [], {}, [None], np.zeros(1))
    out = S._continued(None, base, cand, None, 1, Settings())
    assert (out is not None) == continued
    if continued:
        assert calls == [([0.01], [[0.0, 44.7e-6]], False)]


@settings(max_examples=4, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([3, 4, 8]))
def test_replay_noise_estimates_the_off_diagonal_squared_covariance_without_bias(seed, m):
    """Over many sets of ``m`` runs, the estimate of sum_{i != j} sigma_ij^2 averages to its value:
    0 for independent entries, |c|^4 - sum c_j^4 for a mode c that moves every entry, where the
    plain sample estimate is biased by tr(Sigma)^2/(m-1)."""
    from ssamb.closeloop.estimate import replay_noise

    rng = np.random.default_rng(seed)
    N = 120
    c = rng.standard_normal(N)
    c *= 8.0 / np.linalg.norm(c)
    cases = [(lambda: 1.2 * rng.standard_normal((m, N)), 0.0, 30.0),
             (lambda: np.outer(rng.standard_normal(m), c) + 0.5 * rng.standard_normal((m, N)),
              64.0 ** 2 - float(np.sum(c ** 4)), 0.0)]
    for draw, t2, atol in cases:
        est = [replay_noise(draw(), None)[1] for _ in range(1500)]
        assert np.mean(est) == pytest.approx(t2, rel=0.1, abs=atol)
    vg, _, _ = replay_noise(cases[0][0](), [np.arange(N // 2), np.arange(N // 2, N)])
    assert vg.shape == (2,)


def test_noise_floor_of_independent_quiet_replays_is_the_old_one():
    """Replays quieter than the whitening's unit and independent between entries: the floor is
    N(1 + rho/m) with N degrees of freedom; a group whose replays are noisier than the unit adds
    its excess (the rig carries it too); one mode shared by many entries leaves few degrees of
    freedom (Satterthwaite: f^2 / tr(Sigma_a^2))."""
    from ssamb.closeloop.estimate import noise_floor

    f, nu = noise_floor(np.array([100, 50]), np.array([0.4, 0.4]), 0.0, 4)
    assert f == pytest.approx(150 * 1.1) and nu == pytest.approx(150)
    f, _ = noise_floor(np.array([100, 50]), np.array([0.4, 3.0]), -5.0, 4)
    assert f == pytest.approx(100 * 1.1 + 50 * 3.75)
    f, nu = noise_floor(np.array([150]), np.array([0.4]), 60.0 ** 2, 4)
    assert nu == pytest.approx(f * f / (150 * 1.1 ** 2 + 1.25 ** 2 * 3600))
    assert nu < 20


def test_a_shared_mode_of_the_replays_is_no_misfit():
    """Every replay (and the data, one more) carries a mode that moves all entries together, the
    data's realisation of it 2.5 standard deviations out: at the truth the cost is far above
    N(1 + rho/m) for independent entries, yet within the noise once its degrees of freedom are
    counted (about 3.4 here; 8 centre runs estimate them); a model with a misfit beside it stays
    far above."""
    from ssamb.closeloop.estimate import _far_above

    N = 200
    rng = np.random.default_rng(5)
    col = rng.standard_normal(N)
    c = rng.standard_normal(N)
    c *= 10.0 / np.linalg.norm(c)
    e_data = rng.standard_normal(N) + 2.5 * c

    def evaluate(theta, seed, misfit=0.0):
        g = np.random.default_rng(seed)
        return (3.0 * col * (theta[0] - 1.0) - e_data + 0.3 * g.standard_normal(N) + g.standard_normal() * c
                + misfit)

    def fit(misfit):
        prob = Problem(("a",), np.zeros(1), np.array([np.inf]), np.array([0.5]), np.array([-5.0]),
                       np.array([5.0]), lambda t, sd: evaluate(t, sd, misfit), start=np.array([1.0]),
                       groups=[np.arange(N)])
        return map_fit(prob, EstimateSettings(max_iter=2, short_iter=0, centre_runs=8))
    at = fit(0.0)
    assert at.chi2 > 3 * at.floor / 2 and _far_above(at.chi2, at.n, at.floor, 1e-3)
    assert at.floor_dof < 10 and not _far_above(at.chi2, at.n, at.floor, 1e-3, at.floor_dof)
    off = fit(np.sqrt(15.0) * np.sign(col))     # a misfit no replay's noise makes: |u|^2 = 3000
    assert _far_above(off.chi2, off.n, off.floor, 1e-3, off.floor_dof)


def test_a_jacobian_of_pure_noise_shared_by_whole_views_is_not_determined():
    """A Jacobian that is pure noise, its rows moved together by three shared modes (a replay's
    state moving whole views): noise worth about 3 independent entries of 200. Counted as 200,
    its largest eigenvalues pass ``min_snr`` in most draws (the Marchenko-Pastur edge for 10
    parameters and 3 entries is 8.5); counted as the replicates measure them (3.3 here), in
    fewer than 5 %."""
    from ssamb.closeloop.estimate import _information, effective_entries, replay_noise

    N, p, rng = 200, 10, np.random.default_rng(8)
    A = rng.standard_normal((N, 3))
    A *= 10.0 / np.linalg.norm(A, axis=0)
    sigma = 0.3
    noise = (float(np.sum(A * A)) + N * sigma ** 2) * np.eye(p)
    runs = np.array([A @ rng.standard_normal(3) + sigma * rng.standard_normal(N) for _ in range(400)])
    nu = effective_entries(np.array([N]), *replay_noise(runs, None))
    assert 2.5 < nu < 4.5
    s = EstimateSettings()
    kept = {N: 0, nu: 0}
    for _ in range(200):
        E = A @ rng.standard_normal((3, p)) + sigma * rng.standard_normal((N, p))
        for n in kept:
            kept[n] += _information(E, noise, np.ones(p), s, np.ones(p), n)[1].shape[1] > 0
    assert kept[N] > 100 and kept[nu] < 10, kept
