"""Tests of ssamb.identification: SIPPY wrapper on synthetic systems, fit metric, operating point, files."""
from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from ssamb.io import DataError
from ssamb.identification import (
    IdentifiedModel,
    auto_horizon,
    check_io_data,
    compare_methods,
    identify,
    input_excitation,
    nrmse_fit,
    order_scan,
    subspace_singular_values,
    subsystem_io,
)
from ssamb.identification.model import _state_regressors
from ssamb.model_io import load_model, save_model

# ---------------------------------------------------------------------------------------
# a known stable MIMO system (2 inputs, 2 outputs, order 4) with an operating point
# ---------------------------------------------------------------------------------------
R, TH = 0.9, 0.5
A_TRUE = np.array([[R * np.cos(TH), -R * np.sin(TH), 0, 0],
                   [R * np.sin(TH), R * np.cos(TH), 0, 0],
                   [0, 0, 0.7, 0],
                   [0, 0, 0, -0.5]])
POLES_TRUE = np.linalg.eigvals(A_TRUE)
# every mode well controllable and observable (Hankel singular values 6.6, 4.9, 1.8, 1.6)
B_TRUE = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, -1.0]])
C_TRUE = np.array([[1.0, 0.5, 1.0, 0.0], [0.0, 1.0, 0.0, 1.0]])
B1_TRUE = np.array([0.3, -0.2, 0.1, 0.5])  # operating-point (affine) terms
D1_TRUE = np.array([1.0, 2.0])
U_OP = np.array([3.0, -1.0])  # inputs are pulses about this (non-zero) operating point
FS = 1000.0


def _pulses(n, n_ch, seed, hold=5):
    rng = np.random.default_rng(seed)
    return np.repeat(rng.standard_normal((n // hold + 1, n_ch)), hold, axis=0)[:n]


def _simulate_true(u, x0="steady"):
    w = np.column_stack([u, np.ones(len(u))])
    Ba = np.column_stack([B_TRUE, B1_TRUE])
    Da = np.column_stack([np.zeros((2, 2)), D1_TRUE])
    if isinstance(x0, str):
        x0 = np.linalg.solve(np.eye(4) - A_TRUE, Ba @ w[0])
    _, y, _ = scipy.signal.dlsim((A_TRUE, Ba, C_TRUE, Da, 1.0), w, x0=x0)
    return y


def _true_equilibrium(u_const):
    x = np.linalg.solve(np.eye(4) - A_TRUE, B_TRUE @ u_const + B1_TRUE)
    return C_TRUE @ x + D1_TRUE


NOISE = 1e-3  # output noise, relative to the output standard deviation (60 dB SNR)


def _noisy(y, seed):
    return y + NOISE * y.std(axis=0) * np.random.default_rng(seed).standard_normal(y.shape)


@pytest.fixture(scope="module")
def data():
    u = U_OP + _pulses(5000, 2, seed=1)
    y = _noisy(_simulate_true(u), seed=11)
    uv = U_OP + _pulses(2500, 2, seed=2)
    yv = _noisy(_simulate_true(uv), seed=12)
    return u, y, uv, yv


@pytest.fixture(scope="module")
def model(data):
    u, y, _, _ = data
    return identify(u, y, 4, "N4SID", FS, ["a", "b"], ["p", "q"], ss_f=12, ss_p=12)


# ---------------------------------------------------------------------------------------
# fit metric
# ---------------------------------------------------------------------------------------
def test_nrmse_fit_definition_hand_cases():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    assert nrmse_fit(y, y) == 100.0
    assert nrmse_fit(y, np.full(4, y.mean())) == pytest.approx(0.0)
    # error of half the deviation norm -> 50 %
    dev = y - y.mean()
    assert nrmse_fit(y, y + 0.5 * dev) == pytest.approx(50.0)
    # worse than the mean -> negative
    assert nrmse_fit(y, y + 3 * dev) == pytest.approx(-200.0)


def test_nrmse_fit_is_per_channel_not_pooled():
    t = np.linspace(0, 1, 200)
    good = np.sin(2 * np.pi * 3 * t)
    bad = 1e-3 * np.cos(2 * np.pi * 5 * t)  # a tiny-amplitude channel
    y = np.column_stack([good, bad])
    yhat = np.column_stack([good, bad + 0.25 * (bad - bad.mean())])
    fit = nrmse_fit(y, yhat)
    assert fit.shape == (2,)
    assert fit[0] == 100.0
    assert fit[1] == pytest.approx(75.0)
    # pooling the channels would hide the bad one behind the large-amplitude good one
    pooled = 100 * (1 - np.linalg.norm(y - yhat) / np.linalg.norm(y - y.mean(axis=0)))
    assert pooled > 99.9
    # constant channel: undefined; non-finite prediction: -inf
    f2 = nrmse_fit(np.column_stack([good, np.ones(200)]), np.column_stack([good * np.nan, np.ones(200)]))
    assert f2[0] == -np.inf and np.isnan(f2[1])
    with pytest.raises(ValueError, match="shape"):
        nrmse_fit(y, yhat[:, :1])


# ---------------------------------------------------------------------------------------
# recovery of a known system
# ---------------------------------------------------------------------------------------
def _pole_error(est, true):
    est = np.asarray(est)
    used = set()
    err = 0.0
    for p in true:
        d = np.abs(est - p)
        for j in used:
            d[j] = np.inf
        j = int(np.argmin(d))
        used.add(j)
        err = max(err, d[j])
    return err


@pytest.mark.slow
@pytest.mark.parametrize("method", ["N4SID", "PARSIM-K"])
def test_recovers_known_mimo_system(data, method):
    u, y, uv, yv = data
    m = identify(u, y, 4, method, FS, ["a", "b"], ["p", "q"], ss_f=12, ss_p=12)
    assert m.order == 4 and m.method == method
    assert _pole_error(m.poles, POLES_TRUE) < 1e-3
    fit = m.fit(uv, yv)  # stable: pure simulation from the least-squares initial state
    assert fit.shape == (2,) and np.all(fit > 99.0), fit
    assert m.is_stable and auto_horizon(m.A, len(uv)) is None
    # the DC gain (hence the equilibrium at the operating point) is right
    np.testing.assert_allclose(m.equilibrium(U_OP)[1], _true_equilibrium(U_OP), rtol=1e-3)


@pytest.mark.slow
def test_refine_improves_simulation_fit(data):
    u, y, uv, yv = data
    plain = identify(u, y, 4, "MOESP", FS, ss_f=12, ss_p=12, refine="none")
    ref = identify(u, y, 4, "MOESP", FS, ss_f=12, ss_p=12, refine="auto")
    assert ref.info["refine"]["mode"] == "simulation"
    np.testing.assert_array_equal(ref.A, plain.A)  # only B, D (and the affine columns) change
    assert np.mean(ref.fit(uv, yv)) >= np.mean(plain.fit(uv, yv)) - 1e-3
    assert np.all(ref.fit(uv, yv) > 99.85)  # the noise floor is 100 (1 - 1e-3) = 99.9


# ---------------------------------------------------------------------------------------
# operating point
# ---------------------------------------------------------------------------------------
def test_operating_point_survives_in_the_affine_model(model, data):
    u, y, _, _ = data
    assert model.affine and model.all_input_names == ("a", "b", "one")
    assert model.B.shape == (4, 3) and model.D.shape == (2, 3)
    # the model's own equilibrium at the data's operating input is the data's set point
    y_true_op = _true_equilibrium(model.u_op)
    np.testing.assert_allclose(model.y_op, y_true_op, rtol=1e-3)
    # simulated from its own initial condition (the equilibrium) with the inputs held at the
    # operating point, the model stays at the set point: no drift, no start-up transient
    u_const = np.tile(U_OP, (500, 1))
    y_sim = model.simulate(u_const)
    np.testing.assert_allclose(y_sim, np.tile(_true_equilibrium(U_OP), (500, 1)), rtol=1e-3)
    assert np.ptp(y_sim, axis=0).max() < 1e-9
    # and a step response from there converges to the true new equilibrium
    u_step = np.tile(U_OP + [0.5, -0.2], (400, 1))
    y_step = model.simulate(u_step, x0=model.equilibrium(U_OP)[0])
    np.testing.assert_allclose(y_step[-1], _true_equilibrium(U_OP + [0.5, -0.2]), rtol=1e-3)


@pytest.mark.slow
def test_without_operating_point_the_dynamics_are_distorted(data):
    """What the paper warns against: a purely linear model of undetrended data has to bend its
    DC gain to mimic the offset at the operating point, and is wrong everywhere else."""
    u, y, uv, yv = data
    G_true = C_TRUE @ np.linalg.solve(np.eye(4) - A_TRUE, B_TRUE)

    def dc_gain(m):
        return m.C @ np.linalg.solve(np.eye(4) - m.A, m.B[:, :2]) + m.D[:, :2]

    lin = identify(u, y, 4, "N4SID", FS, ss_f=12, ss_p=12, affine=False)
    aff = identify(u, y, 4, "N4SID", FS, ss_f=12, ss_p=12)
    assert lin.B.shape == (4, 2) and aff.B.shape == (4, 3)
    err_lin = np.abs(dc_gain(lin) - G_true).max()
    err_aff = np.abs(dc_gain(aff) - G_true).max()
    assert err_aff < 1e-3 < 0.1 < err_lin
    u_off = U_OP + [1.0, 1.0]  # away from the operating point
    assert np.abs(aff.equilibrium(u_off)[1] - _true_equilibrium(u_off)).max() < 1e-3
    assert np.abs(lin.equilibrium(u_off)[1] - _true_equilibrium(u_off)).max() > 0.1


def test_initial_state_least_squares(model):
    """Data that start away from equilibrium: the LS initial state removes the transient."""
    uv = U_OP + _pulses(1500, 2, seed=5)
    x0 = np.array([3.0, -2.0, 1.0, 4.0])
    yv = _simulate_true(uv, x0=x0)
    fit_ls = model.fit(uv, yv, x0="ls")
    fit_steady = model.fit(uv, yv, x0="steady")
    assert np.all(fit_ls > 99.0) and np.all(fit_ls > fit_steady)


def test_unstable_plant_in_closed_loop_uses_prediction_fit():
    """An open-loop unstable SISO plant identified from closed-loop data (like the AMB plant)."""
    a = np.array([[1.002, 0.01], [0.0, 0.9]])
    b = np.array([[0.0], [1.0]])
    c = np.array([[1.0, 0.0]])
    kfb = 0.05  # u = r - kfb * y stabilises it
    acl = a - kfb * b @ c
    assert np.max(np.abs(np.linalg.eigvals(acl))) < 1
    n = 6000
    r = 2.0 + _pulses(n, 1, seed=9, hold=30)[:, 0]
    _, yy, xx = scipy.signal.dlsim((acl, b, c, np.zeros((1, 1)), 1.0), r[:, None])
    u = r - kfb * yy[:, 0]
    m = identify(u, yy, 2, "PARSIM-K", FS, ["u"], ["y"], ss_f=10, ss_p=10)
    assert _pole_error(m.poles, np.linalg.eigvals(a)) < 1e-3
    assert not m.is_stable
    h = auto_horizon(m.A, n)
    assert h is not None and 100 < h < 2000  # ~ 1/ln(1.002) = 500 samples
    fit = m.fit(u, yy)  # 'auto': k-step prediction with the model's predictor gain
    assert fit[0] > 99.0


# ---------------------------------------------------------------------------------------
# bad data
# ---------------------------------------------------------------------------------------
def test_bad_data_errors(data):
    u, y, _, _ = data
    u_nan = u.copy()
    u_nan[100, 1] = np.nan
    with pytest.raises(DataError, match="'b'.*non-finite"):
        identify(u_nan, y, 4, "N4SID", FS, ["a", "b"], ["p", "q"], ss_f=12, ss_p=12)
    y_inf = y.copy()
    y_inf[7, 0] = np.inf
    with pytest.raises(DataError, match="'p'.*first at sample 7"):
        identify(u, y_inf, 4, "N4SID", FS, ["a", "b"], ["p", "q"], ss_f=12, ss_p=12)
    with pytest.raises(DataError, match="too short"):
        identify(u[:100], y[:100], 4, "N4SID", FS, ss_f=12, ss_p=12)
    u_const = u.copy()
    u_const[:, 0] = 3.57
    with pytest.raises(DataError, match="'a' is constant.*no excitation"):
        identify(u_const, y, 4, "N4SID", FS, ["a", "b"], ["p", "q"], ss_f=12, ss_p=12)
    with pytest.raises(DataError, match="lengths must match"):
        identify(u[:-5], y, 4, "N4SID", FS, ss_f=12, ss_p=12)
    with pytest.raises(DataError, match="smaller than the future horizon"):
        identify(u, y, 12, "N4SID", FS, ss_f=12, ss_p=12)
    with pytest.raises(DataError, match="name"):
        identify(u, y, 4, "N4SID", FS, ["a"], ["p", "q"], ss_f=12, ss_p=12)
    with pytest.raises(ValueError, match="unknown method"):
        identify(u, y, 4, "FOO", FS)
    assert issubclass(DataError, ValueError)


def test_rank_deficient_inputs_get_minimum_norm_model():
    """Two inputs excited only in their difference (like the coil pairs): the common mode is
    not identifiable; the model gets zero gain along it, and the difference is recovered."""
    n = 5000
    d = _pulses(n, 1, seed=3)[:, 0]
    u = np.column_stack([3.57 + d, 2.43 - d])  # common mode constant (6 A)
    a, b = 0.9, 0.05
    # true plant responds to 1.0 * i1 - 0.7 * i2 (a common-mode gain exists physically)
    _, y, _ = scipy.signal.dlsim(([[a]], [[b, -0.7 * b]], [[1.0]], [[0.0, 0.0]], 1.0), u,
                                 x0=[b * (3.57 - 0.7 * 2.43) / (1 - a)])
    exc = input_excitation(u)
    assert exc["relative_singular_values"][-1] < 1e-10
    with pytest.warns(UserWarning, match="unexcited direction"):
        m = identify(u, y, 1, "N4SID", FS, ["i1", "i2"], ["y"], ss_f=8, ss_p=8)
    G1 = (m.C @ np.linalg.solve(np.eye(1) - m.A, m.B[:, :2]) + m.D[:, :2])[0]
    # the differential gain G(1)(1, -1) is right: (1 + 0.7) b / (1 - a)
    assert G1 @ [1, -1] == pytest.approx(1.7 * b / (1 - a), rel=5e-3)
    # no gain in the unexcited direction (1, 1)/std-scaled: minimum norm
    assert abs(G1 @ [1, 1]) < 1e-6 * abs(G1 @ [1, -1])
    # the set point is still reproduced (it lives in the affine column)
    ub = u.mean(axis=0)
    assert m.y_op[0] == pytest.approx(b * (ub[0] - 0.7 * ub[1]) / (1 - a), rel=1e-3)
    # user-chosen directions (the differential current) give the same model
    m2 = identify(u, y, 1, "N4SID", FS, ["i1", "i2"], ["y"], ss_f=8, ss_p=8, input_directions=[[1.0, -1.0]])
    G2 = (m2.C @ np.linalg.solve(np.eye(1) - m2.A, m2.B[:, :2]))[0]
    np.testing.assert_allclose(G2, G1, rtol=1e-3)


# ---------------------------------------------------------------------------------------
# order scan and method comparison
# ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_order_scan_finds_the_true_order(data):
    u, y, uv, yv = data
    scan = order_scan(u[:3000], y[:3000], orders=range(2, 7), method="N4SID", fs_hz=FS,
                      u_val=uv, y_val=yv, ss_f=10, ss_p=10)
    assert scan.fits.shape == (5, 2)
    assert scan.smallest_order_within(0.1) == 4
    assert np.all(scan.fits[scan.orders.tolist().index(4)] > 99.0)
    # SIPPY's singular values: a gap after the 4th
    sv = scan.singular_values
    assert sv[3] / sv[4] > 100 * (sv[2] / sv[3])
    json.dumps(scan.as_dict())


@pytest.mark.slow
def test_compare_methods_reports_each_method(data):
    u, y, uv, yv = data
    res = compare_methods(u[:3000], y[:3000], 4, methods=("N4SID", "MOESP", "CVA", "PARSIM-K"), fs_hz=FS,
                          u_val=uv, y_val=yv, ss_f=10, ss_p=10)
    assert [r.method for r in res] == ["N4SID", "MOESP", "CVA", "PARSIM-K"]
    for r in res:
        assert r.error is None and r.stable and r.spectral_radius < 1
        assert r.mean_fit > 99.0
        json.dumps(r.as_dict())


def test_singular_values_parsim_k(data):
    u, y, _, _ = data
    sv = subspace_singular_values(u[:3000], y[:3000], "PARSIM-K", ss_f=10, ss_p=10)
    assert sv[3] / sv[4] > 1e3


# ---------------------------------------------------------------------------------------
# files, state-space object, subsystem data
# ---------------------------------------------------------------------------------------
def test_save_load_round_trip(model, tmp_path):
    path = tmp_path / "models" / "plant.npz"
    save_model(path, model)
    assert path.exists() and path.with_suffix(".json").exists()
    back = load_model(path)
    for k in ("A", "B", "C", "D", "u_op", "y_op", "K"):
        np.testing.assert_array_equal(getattr(back, k), getattr(model, k))
    assert back.input_names == model.input_names and back.output_names == model.output_names
    assert back.dt == model.dt and back.method == model.method and back.data_hash == model.data_hash
    ss1, ss2 = model.to_statespace(), back.to_statespace()
    assert list(ss2.input_labels) == ["a", "b", "one"] and list(ss2.output_labels) == ["p", "q"]
    assert ss2.dt == pytest.approx(1 / FS)
    z = np.exp(1j * 0.37)
    np.testing.assert_array_equal(ss1(z), ss2(z))
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["order"] == 4 and meta["method"] == "N4SID"
    with pytest.raises(DataError):
        load_model(tmp_path / "missing.npz")


def test_data_hash_identifies_the_data(data, model):
    u, y, _, _ = data
    m2 = identify(u[:-1], y[:-1], 4, "N4SID", FS, ["a", "b"], ["p", "q"], ss_f=12, ss_p=12)
    assert m2.data_hash != model.data_hash and len(model.data_hash) == 64


def test_subsystem_io_columns():
    n = 10
    rng = np.random.default_rng(0)
    cols = ["t", "r_x", "r_y", "x_meas", "y_meas", "y_ss", "i_ypos", "i_yneg", "i_xpos", "i_xneg",
            "u_x", "u_y", "inj_x", "inj_y"]
    arr = {c: rng.standard_normal(n) for c in cols}
    p = subsystem_io(arr, "plant")
    assert p.input_names == ("i_ypos", "i_yneg", "i_xpos", "i_xneg") and p.output_names == ("x_meas", "y_meas")
    np.testing.assert_array_equal(p.u[:, 1], arr["i_yneg"])
    a = subsystem_io(arr, "amplifier", "full")  # the paper's 4-input amplifier
    np.testing.assert_array_equal(a.u[:, 0], arr["u_x"] + arr["inj_x"])
    np.testing.assert_array_equal(a.u[:, 1], arr["u_y"] + arr["inj_y"])
    np.testing.assert_array_equal(a.u[:, 3], arr["y_meas"])
    assert a.y.shape == (n, 4)
    u, y, ins, outs = subsystem_io(arr, "selfsensing", "current")
    assert ins == ("i_ypos",) and outs == ("y_ss",) and u.shape == (n, 1)
    assert subsystem_io(arr, "selfsensing").input_names == ("y_meas",)  # ours: DCM as a sensor
    assert subsystem_io(arr, "amplifier").input_names == ("u_x_cmd", "u_y_cmd")
    del arr["inj_x"]
    np.testing.assert_array_equal(subsystem_io(arr, "amplifier").u[:, 0], arr["u_x"])
    del arr["i_yneg"]
    with pytest.raises(DataError, match="i_yneg"):
        subsystem_io(arr, "plant")
    with pytest.raises(ValueError, match="subsystem 'rotor'"):
        subsystem_io(arr, "rotor")


def test_fast_simulators_equal_sippy():
    from sippy_unipi.functionsetSIM import SS_lsim_predictor_form, SS_lsim_process_form

    from ssamb.identification.sippy_fast import _fast_predictor_form, _fast_process_form

    rng = np.random.default_rng(1)
    n, m, l_, N = 3, 2, 2, 50
    A = 0.5 * rng.standard_normal((n, n))
    B, C = rng.standard_normal((n, m)), rng.standard_normal((l_, n))
    D, K = rng.standard_normal((l_, m)), rng.standard_normal((n, l_))
    u, y, x0 = rng.standard_normal((m, N)), rng.standard_normal((l_, N)), rng.standard_normal((n, 1))
    for a, b in zip(SS_lsim_process_form(A, B, C, D, u, x0), _fast_process_form(A, B, C, D, u, x0)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    for a, b in zip(SS_lsim_predictor_form(A, B, C, D, K, y, u, x0), _fast_predictor_form(A, B, C, D, K, y, u, x0)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    for a, b in zip(SS_lsim_process_form(A, B, C, D, u), _fast_process_form(A, B, C, D, u)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_check_io_data_accepts_1d():
    u = np.sin(np.arange(500) * 0.3)
    y = np.cos(np.arange(500) * 0.3)
    uu, yy, ins, outs = check_io_data(u, y, "u", "y", 5, 5)
    assert uu.shape == (500, 1) and ins == ("u",) and outs == ("y",)
    assert isinstance(IdentifiedModel, type)


def test_k_step_prediction_matches_brute_force():
    rng = np.random.default_rng(0)
    A = np.array([[1.01, 0.1], [0.0, 0.5]])  # unstable
    m = IdentifiedModel(A=A, B=rng.standard_normal((2, 3)), C=rng.standard_normal((2, 2)),
                        D=rng.standard_normal((2, 3)), dt=1.0, method="hand", input_names=("a", "b"),
                        output_names=("p", "q"), u_op=np.zeros(2), y_op=np.zeros(2))
    n = 120
    u, y, x0 = rng.standard_normal((n, 2)), rng.standard_normal((n, 2)), rng.standard_normal(2)
    K = m.predictor_gain()
    assert np.max(np.abs(np.linalg.eigvals(A - K @ m.C))) < 1
    w = np.column_stack([u, np.ones(n)])
    xp = [x0]
    for t in range(n):
        xp.append(A @ xp[-1] + m.B @ w[t] + K @ (y[t] - m.C @ xp[-1] - m.D @ w[t]))
    for k in (1, 2, 9):
        ref = np.zeros_like(y)
        for t in range(n):
            start = 0 if t < k - 1 else t - k + 1
            x = x0.copy() if t < k - 1 else xp[start].copy()
            for j in range(start, t):
                x = A @ x + m.B @ w[j]
            ref[t] = m.C @ x + m.D @ w[t]
        np.testing.assert_allclose(m.predict(u, y, k, x0=x0), ref, rtol=1e-10, atol=1e-10)


def test_hankel_excitation_flags_dynamically_dependent_inputs():
    rng = np.random.default_rng(3)
    a = _pulses(4000, 1, seed=4)[:, 0]
    b = rng.standard_normal(4000)
    # c is a causal filtered copy of a (like a position generated by the loop from the command)
    c = scipy.signal.lfilter([0.0, 0.3], [1.0, -0.7], a)
    free = input_excitation(np.column_stack([a, b]), hankel_rows=10)
    dep = input_excitation(np.column_stack([a, b, c]), hankel_rows=10)
    assert free["hankel_relative_singular_values"].shape == (20,)
    assert dep["hankel_min_relative_sv"] < 1e-6 < free["hankel_min_relative_sv"]
    # instantaneous singular values do not see it
    assert dep["relative_singular_values"][-1] > 1e-2


# ---------------------------------------------------------------------------------------
# the memo of shared work (ssamb.identification.memo): bit-identical results
# ---------------------------------------------------------------------------------------
def _matrices(m):
    return [np.asarray(a).tobytes() for a in (m.A, m.B, m.C, m.D, m.K, m.u_op, m.y_op)]


def test_memo_gives_bit_identical_models_and_reuses_the_shared_work(data):
    """Every method, identified afresh (no memo, plain SIPPY) and inside one memo after the
    others (so that the operating point, the projections and the weighted SVD come from memory),
    gives the same bits; the forced-stable variant and a second order reuse the same SVD."""
    from ssamb.identification.memo import identification_memo, no_memo

    u, y, _, _ = data
    runs = [("N4SID", 4, False), ("MOESP", 4, False), ("CVA", 4, False), ("PARSIM-K", 4, False),
            ("N4SID", 4, True), ("MOESP", 3, False), ("PARSIM-K", 3, False)]
    with no_memo():
        fresh = [identify(u, y, n, meth, FS, ss_f=12, ss_p=12, A_stability=stab) for meth, n, stab in runs]
    with identification_memo() as memo:
        shared = [identify(u, y, n, meth, FS, ss_f=12, ss_p=12, A_stability=stab) for meth, n, stab in runs]
    assert memo.hits >= 10
    for (meth, n, stab), a, b in zip(runs, fresh, shared):
        assert _matrices(a) == _matrices(b), (meth, n, stab)
    # outside the block SIPPY is untouched and nothing is kept
    from sippy_unipi import OLSims_methods, functionsetSIM

    assert OLSims_methods.Z_dot_PIort is functionsetSIM.Z_dot_PIort
    assert OLSims_methods.SVD_weighted.__module__ == "sippy_unipi.OLSims_methods"


def test_memo_hands_out_read_only_arrays():
    from ssamb.identification.memo import identification_memo, memoised

    with identification_memo():
        a = memoised("twice", lambda x: 2 * x, np.arange(3.0))
        b = memoised("twice", lambda x: 3 * x, np.arange(3.0))  # a hit: the first value
        assert b is a and not a.flags.writeable
        with pytest.raises(ValueError):
            a[0] = 1.0
    assert memoised("twice", lambda x: 3 * x, np.arange(3.0))[1] == 3.0  # no memo outside


# ---------------------------------------------------------------------------------------
# the compiled regressor recursion of the least-squares refinement
# ---------------------------------------------------------------------------------------
@settings(max_examples=25, deadline=None)
@given(n=st.integers(0, 4), l_=st.integers(1, 3), q=st.integers(1, 3), N=st.integers(0, 12),
       seed=st.integers(0, 2**32 - 1))
def test_state_regressors_are_the_derivative_of_the_output_by_the_input_matrix(n, l_, q, N, seed):
    """R[t, :, j, k] = sum_{s<t} C F^(t-1-s) e_j w[s, k], summed term by term, and the
    output of x+ = F x + G w is linear in G: y = sum_jk G_jk R[:, :, j, k]."""
    rng = np.random.default_rng(seed)
    F = 0.5 * rng.normal(size=(n, n))
    C, w = rng.normal(size=(l_, n)), rng.normal(size=(N, q))
    R = _state_regressors(F, C, w)
    assert R.shape == (N, l_, n, q)
    expect = np.zeros((N, l_, n, q))
    for t in range(N):
        for s in range(t):
            P = C @ np.linalg.matrix_power(F, t - 1 - s)  # (l, n): column j is C F^(t-1-s) e_j
            expect[t] += P[:, :, None] * w[s][None, None, :]
    np.testing.assert_allclose(R, expect, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(expect).max(initial=0)))
    G = rng.normal(size=(n, q))
    x, y = np.zeros(n), np.zeros((N, l_))
    for t in range(N):
        y[t] = C @ x
        x = F @ x + G @ w[t]
    np.testing.assert_allclose(np.einsum("tljk,jk->tl", R, G), y, rtol=1e-10, atol=1e-10)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 6), ratio=st.integers(4, 30), rank_drop=st.integers(0, 2), wide=st.booleans(),
       seed=st.integers(0, 2**32 - 1))
def test_pinv_qr_is_the_moore_penrose_inverse(n, ratio, rank_drop, wide, seed):
    """The four Penrose conditions, and numpy's SVD pseudo-inverse to round-off, on long
    matrices of full and of deficient rank (a clear gap below the kept singular values)."""
    from ssamb.identification.sippy_fast import pinv_qr

    rng = np.random.default_rng(seed)
    r = max(n - rank_drop, 1)
    a = rng.normal(size=(n * ratio, r)) @ rng.normal(size=(r, n))
    a = a.T if wide else a
    p = pinv_qr(a)
    assert p.shape == a.T.shape
    tol = dict(rtol=1e-9, atol=1e-9 * np.abs(a).max())
    np.testing.assert_allclose(a @ p @ a, a, **tol)
    np.testing.assert_allclose(p @ a @ p, p, rtol=1e-9, atol=1e-9 * np.abs(p).max())
    np.testing.assert_allclose(a @ p, (a @ p).T, atol=1e-9)
    np.testing.assert_allclose(p @ a, (p @ a).T, atol=1e-9)
    if r == n:  # the rank-deficient cases' cutoff sits in round-off: compare the full-rank ones
        np.testing.assert_allclose(p, np.linalg.pinv(a), rtol=1e-8, atol=1e-10 * np.abs(p).max())
