"""Tests of ssamb.loop: closed-loop assembly against hand-derived loops, simulation, d2c."""
from __future__ import annotations

import warnings

import control
import numpy as np
import pytest

from ssamb.identification import IdentifiedModel
from ssamb.closed_loop import (
    CL_OUTPUTS,
    assemble_closed_loop,
    d2c_error,
    d2c_pole_sensitivity,
    equilibrium,
    simulate_closed_loop,
    stability,
    to_continuous,
)

FS = 83300.0
DT = 1.0 / FS
CUR = ["i_ypos", "i_yneg", "i_xpos", "i_xneg"]


def _z(f_hz, dt=DT):
    return np.exp(2j * np.pi * f_hz * dt)


def _static(gain, inputs, outputs, name, dt=DT):
    """A static gain as a StateSpace with no states (gain: l x m)."""
    g = np.atleast_2d(np.asarray(gain, float))
    return control.ss(np.zeros((0, 0)), np.zeros((0, g.shape[1])), np.zeros((g.shape[0], 0)), g, dt,
                      inputs=inputs, outputs=outputs, name=name)


def _first_order(a, b, inputs, outputs, name, dt=DT, c=1.0):
    """x+ = a x + b u, y = c x (SISO, strictly proper)."""
    return control.ss([[a]], [[b]], [[c]], [[0.0]], dt, inputs=inputs, outputs=outputs, name=name)


def _pi(kp, ki_dt, dt=DT):
    """Discrete PI C(z) = kp + ki_dt / (z - 1): state-space x+ = x + e, u = ki_dt x + kp e."""
    return control.ss([[1.0]], [[1.0]], [[ki_dt]], [[kp]], dt)


# --------------------------------------------------------------------------------------
# SISO: assemble a loop where only the x axis matters and compare with T = PC / (1 + PC)
# --------------------------------------------------------------------------------------
def _siso_setup():
    """x loop: amplifier i_xpos = u_x_cmd (static), plant x = P(z) i_xpos, PI controller.

    Everything else is decoupled: the y loop (through a first-order self-sensing) is stable
    and does not touch x.
    """
    a_p, b_p = 0.999, 2e-3  # plant P(z) = b_p / (z - a_p)
    kp, ki = 0.5, 0.01
    amp = np.zeros((4, 4))
    amp[2, 0] = 1.0  # i_xpos = u_x_cmd
    amp[0, 1] = 1.0  # i_ypos = u_y_cmd
    amplifier = _static(amp, ["u_x_cmd", "u_y_cmd", "x_meas", "y_meas"], CUR, "amplifier")
    # plant: x from i_xpos through P; y from i_ypos through a stable first order
    plant = control.ss(np.diag([a_p, 0.5]), np.array([[0, 0, b_p, 0], [0.2, 0, 0, 0]]), np.eye(2),
                       np.zeros((2, 4)), DT, inputs=CUR, outputs=["x_meas", "y_meas"], name="plant")
    selfsensing = _first_order(0.5, 0.1, ["i_ypos"], ["y_ss"], "selfsensing")  # stable y loop
    pid = _pi(kp, ki)
    return plant, amplifier, selfsensing, pid, (a_p, b_p, kp, ki)


def test_siso_loop_matches_analytic_complementary_sensitivity():
    plant, amplifier, selfsensing, pid, (a_p, b_p, kp, ki) = _siso_setup()
    cl = assemble_closed_loop(plant, amplifier, selfsensing, pid, pid)
    assert list(cl.output_labels) == list(CL_OUTPUTS)
    assert list(cl.input_labels) == ["r_x", "r_y", "inj_x", "inj_y"]
    i_rx = cl.input_labels.index("r_x")
    i_x = cl.output_labels.index("x_meas")
    i_ux = cl.output_labels.index("u_x")
    i_injx = cl.input_labels.index("inj_x")
    for f in (1.0, 10.0, 123.0, 1e3, 1e4, 4e4):
        z = _z(f)
        P = b_p / (z - a_p)
        C = kp + ki / (z - 1.0)
        L = P * C
        H = cl(z)
        assert abs(H[i_x, i_rx] - L / (1 + L)) < 1e-10 * max(1.0, abs(L / (1 + L)))
        # control sensitivity r -> u and input disturbance inj -> x
        assert abs(H[i_ux, i_rx] - C / (1 + L)) < 1e-10 * max(1.0, abs(C / (1 + L)))
        assert abs(H[i_x, i_injx] - P / (1 + L)) < 1e-10 * max(1.0, abs(P / (1 + L)))
    rep = stability(cl)
    assert rep.stable and rep.spectral_radius < 1


def test_mimo_identity_like_loop_matches_hand_derivation():
    """Amplifier = identity on the commands (i_xpos = u_x_cmd, i_xneg = -u_x_cmd, likewise y),
    plant = differential force through first-order lags, self-sensing = gain on i_ypos.

    By hand (z-domain): i_xpos - i_xneg = 2 u_x_cmd, x = P_x (2 u_x_cmd),
    x loop: T_x = 2 P_x C / (1 + 2 P_x C). y loop: y_ss = S i_ypos = S u_y_cmd with S = s/z (a
    one-sample delay, so that no algebraic loop forms), y = P_y 2 u_y_cmd; the controller sees
    y_ss: u_y = C (r_y - S u_y_cmd) -> u_y_cmd / r_y = C / (1 + S C),
    y / r_y = 2 P_y C / (1 + S C), y_ss / r_y = S C / (1 + S C).
    """
    amp = np.zeros((4, 4))
    amp[0, 1], amp[1, 1] = 1.0, -1.0
    amp[2, 0], amp[3, 0] = 1.0, -1.0
    amplifier = _static(amp, ["u_x_cmd", "u_y_cmd", "x_meas", "y_meas"], CUR, "amplifier")
    ax, bx, ay, by = 0.99, 1e-3, 0.98, 2e-3
    A = np.diag([ax, ay])
    B = np.array([[0, 0, bx, -bx], [by, -by, 0, 0]])
    plant = control.ss(A, B, np.eye(2), np.zeros((2, 4)), DT, inputs=CUR, outputs=["x_meas", "y_meas"])
    s_gain = 0.3
    selfsensing = control.ss([[0.0]], [[1.0]], [[s_gain]], [[0.0]], DT, inputs=["i_ypos"], outputs=["y_ss"])
    pid = _pi(0.8, 0.02)
    cl = assemble_closed_loop(plant, amplifier, selfsensing, pid, pid)
    ins, outs = list(cl.input_labels), list(cl.output_labels)
    for f in (2.0, 50.0, 800.0, 2e4):
        z = _z(f)
        C = 0.8 + 0.02 / (z - 1)
        Px = bx / (z - ax)
        Py = by / (z - ay)
        S = s_gain / z
        H = cl(z)
        Tx = 2 * Px * C / (1 + 2 * Px * C)
        np.testing.assert_allclose(H[outs.index("x_meas"), ins.index("r_x")], Tx, rtol=1e-10)
        np.testing.assert_allclose(H[outs.index("y_meas"), ins.index("r_y")], 2 * Py * C / (1 + S * C), rtol=1e-10)
        np.testing.assert_allclose(H[outs.index("y_ss"), ins.index("r_y")], S * C / (1 + S * C), rtol=1e-10)
        np.testing.assert_allclose(H[outs.index("i_yneg"), ins.index("r_y")], -C / (1 + S * C), rtol=1e-10)
        # axes decoupled
        assert abs(H[outs.index("x_meas"), ins.index("r_y")]) < 1e-14
        # injection inj_y -> u_y: -S C / (1 + S C)
        np.testing.assert_allclose(H[outs.index("u_y"), ins.index("inj_y")], -S * C / (1 + S * C), rtol=1e-10)


def _affine_models():
    """Affine subsystems (IdentifiedModel) with a non-zero operating point.

    amplifier: i = bias + (+-) u_cmd (static, via a fast first-order state), plant: first-order
    lags of the differential currents with a gravity-like offset in y, self-sensing: y_ss = 0.5
    (i_ypos - 3.57), i.e. zero at the operating current.
    """
    a = 0.5
    Ba = np.zeros((4, 5))
    Ba[0, 1], Ba[1, 1], Ba[2, 0], Ba[3, 0] = 1 - a, -(1 - a), 1 - a, -(1 - a)
    Ba[:, 4] = 3.0 * (1 - a)
    amp = IdentifiedModel(A=a * np.eye(4), B=Ba, C=np.eye(4), D=np.zeros((4, 5)), dt=DT, method="hand",
                          input_names=("u_x_cmd", "u_y_cmd", "x_meas", "y_meas"), output_names=tuple(CUR),
                          u_op=np.zeros(4), y_op=np.full(4, 3.0))
    ap = 0.99
    Bp = np.array([[0, 0, 1e-5, -1e-5, 0.0], [1e-5, -1e-5 * 3.57 / 2.43, 0, 0, 0.0]]) * (1 - ap) * 100
    plant = IdentifiedModel(A=ap * np.eye(2), B=Bp, C=np.eye(2), D=np.zeros((2, 5)), dt=DT, method="hand",
                            input_names=tuple(CUR), output_names=("x_meas", "y_meas"),
                            u_op=np.array([3.57, 2.43, 3, 3]), y_op=np.zeros(2))
    ss = IdentifiedModel(A=np.array([[0.3]]), B=np.array([[0.7 * 0.5e-4, -0.7 * 0.5e-4 * 3.57]]), C=np.eye(1),
                         D=np.zeros((1, 2)), dt=DT, method="hand", input_names=("i_ypos",),
                         output_names=("y_ss",), u_op=np.array([3.57]), y_op=np.zeros(1))
    return plant, amp, ss


def test_affine_loop_has_input_one_and_starts_at_operating_point():
    plant, amp, ss = _affine_models()
    pid = _pi(2000.0, 20.0)
    cl = assemble_closed_loop(plant, amp, ss, pid, pid)
    assert "one" in cl.input_labels
    assert stability(cl).stable
    n = 2000
    t = np.arange(n) * DT
    out = simulate_closed_loop(cl, t, np.zeros(n), np.zeros(n))
    # the integrators settle where y_ss = r_y = 0, i.e. i_ypos = 3.57; no start-up transient
    np.testing.assert_allclose(out["y_ss"], 0.0, atol=1e-15)
    np.testing.assert_allclose(out["i_ypos"], 3.57, rtol=1e-12)
    np.testing.assert_allclose(out["u_y"], 0.57, rtol=1e-10)
    np.testing.assert_allclose(out["x_meas"], 0.0, atol=1e-15)
    assert np.ptp(out["states"], axis=0).max() < 1e-12
    # same columns as the nonlinear data
    for c in ("t", "r_x", "r_y", "inj_x", "inj_y", "x_meas", "y_meas", "y_ss", *CUR, "u_x", "u_y"):
        assert c in out and out[c].shape == (n,)


def test_simulate_closed_loop_matches_forced_response_and_tracks_step():
    plant, amp, ss = _affine_models()
    pid = _pi(2000.0, 20.0)
    cl = assemble_closed_loop(plant, amp, ss, pid, pid)
    n = 3000
    t = np.arange(n) * DT
    inj = np.where(t > 5e-3, 0.1, 0.0)
    out = simulate_closed_loop(cl, t, 0.0, 0.0, inj_x=inj)
    U = np.vstack([np.zeros(n), np.zeros(n), inj, np.zeros(n), np.ones(n)])
    x0 = equilibrium(cl, U[:, 0])
    ref = control.forced_response(cl, T=t, U=U, X0=x0)
    np.testing.assert_allclose(out["x_meas"], np.asarray(ref.outputs)[0], rtol=1e-9, atol=1e-18)
    # integral action rejects the input disturbance
    assert abs(out["x_meas"][-1]) < 0.05 * np.max(np.abs(out["x_meas"]))


def test_assembly_errors():
    plant, amplifier, selfsensing, pid, _ = _siso_setup()
    bad_dt = control.ss([[1.0]], [[1.0]], [[1.0]], [[1.0]], 2 * DT)
    with pytest.raises(ValueError, match="sampling times"):
        assemble_closed_loop(plant, amplifier, selfsensing, bad_dt, pid)
    wrong = _static([[1.0]], ["i_yneg"], ["y_ss"], "ss")
    with pytest.raises(ValueError, match="selfsensing"):
        assemble_closed_loop(plant, amplifier, wrong, pid, pid)
    # D-loop: static self-sensing gain * static amplifier * PID feedthrough
    loop_ss = _static([[1.0]], ["i_ypos"], ["y_ss"], "ss")
    with pytest.raises(ValueError, match="algebraic loop"):
        assemble_closed_loop(plant, amplifier, loop_ss, pid, pid)
    # unstable loop (positive feedback through a negative self-sensing gain and a big PI)
    neg = _static([[-1.0]], ["i_ypos"], ["y_ss"], "ss")
    amp_delay = control.ss(np.zeros((4, 4)), np.asarray(amplifier.D), np.eye(4), np.zeros((4, 4)), DT,
                           inputs=list(amplifier.input_labels), outputs=CUR)
    with pytest.raises(ValueError, match="unstable"):
        assemble_closed_loop(plant, amp_delay, neg, pid, _pi(5.0, 1.0), require_stable=True)
    with pytest.warns(UserWarning, match="unstable"):
        assemble_closed_loop(plant, amp_delay, neg, pid, _pi(5.0, 1.0))


# --------------------------------------------------------------------------------------
# d2c
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["tustin", "zoh"])
def test_c2d_d2c_round_trip(method):
    rng = np.random.default_rng(4)
    # a stable continuous MIMO system with dynamics well below Nyquist (41.65 kHz)
    sysc = control.ss([[-200.0, 2000.0, 0], [-2000.0, -200.0, 0], [0, 0, -5000.0]], rng.standard_normal((3, 2)),
                      rng.standard_normal((2, 3)), rng.standard_normal((2, 2)), inputs=["a", "b"], outputs=["c", "d"])
    sysd = control.sample_system(sysc, DT, method=method)
    back = to_continuous(sysd, method)
    assert back.dt == 0 and list(back.input_labels) == ["a", "b"]
    for M, R in ((back.A, sysc.A), (back.B, sysc.B), (back.C, sysc.C), (back.D, sysc.D)):
        np.testing.assert_allclose(M, R, rtol=1e-7, atol=1e-7 * np.max(np.abs(R)))
    for f in (1.0, 300.0, 3000.0):
        np.testing.assert_allclose(back(2j * np.pi * f), sysc(2j * np.pi * f), rtol=1e-8)


def test_tustin_inverse_recovers_the_pid_exactly():
    from ssamb.config import load_config
    from ssamb.sim.controller import pid_continuous, pid_discrete

    cfg = load_config()
    pid = pid_discrete(cfg)
    pc = to_continuous(pid, "tustin")
    ref = pid_continuous(cfg)
    for f in (1.0, 100.0, 2000.0, 3e4):
        s = 2j * np.pi * f
        np.testing.assert_allclose(pc(s), ref(s), rtol=1e-9)
    # the Tustin conversion is exact on the warped frequency axis, not on the physical one
    err_w = d2c_error(pid, pc, warp=True)
    assert err_w["max_abs_mag_db"] < 1e-9 and err_w["max_abs_phase_deg"] < 1e-7
    err = d2c_error(pid, pc, freqs_hz=[10.0, 1e3, 4e4])
    assert abs(err["mag_db"][0]).max() < 1e-4 and abs(err["phase_deg"][-1]).max() > 0.1


def test_d2c_errors_for_bad_poles():
    neg = control.ss([[-0.5]], [[1.0]], [[1.0]], [[0.0]], DT)
    with pytest.raises(ValueError, match="negative real"):
        to_continuous(neg, "zoh")
    to_continuous(neg, "tustin")  # fine
    m1 = control.ss([[-1.0]], [[1.0]], [[1.0]], [[0.0]], DT)
    with pytest.raises(ValueError, match="-1"):
        to_continuous(m1, "tustin")
    with pytest.raises(ValueError):
        to_continuous(control.ss([[-1.0]], [[1.0]], [[1.0]], [[0.0]]), "tustin")


@pytest.mark.parametrize("method", ["tustin", "zoh"])
def test_pole_sensitivity_is_about_fs_and_matches_finite_difference(method):
    a = 0.999
    sysd = control.ss([[a]], [[1.0]], [[1.0]], [[0.0]], DT)
    sens = d2c_pole_sensitivity(sysd, method)
    assert 0.99 < sens["gain_over_fs"][0] < 1.01
    eps = 1e-7
    s0 = to_continuous(sysd, method).A[0, 0]
    s1 = to_continuous(control.ss([[a + eps]], [[1.0]], [[1.0]], [[0.0]], DT), method).A[0, 0]
    np.testing.assert_allclose(abs(s1 - s0) / eps, sens["gain"][0], rtol=1e-4)


def test_to_continuous_keeps_closed_loop_stability():
    plant, amp, ss = _affine_models()
    pid = _pi(2000.0, 20.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cl = assemble_closed_loop(plant, amp, ss, pid, pid)
    clc = to_continuous(cl, "tustin")
    assert np.max(np.linalg.eigvals(clc.A).real) < 0
    assert list(clc.output_labels) == list(CL_OUTPUTS)


def test_replay_uses_the_data_columns():
    from ssamb.identification import nrmse_fit
    from ssamb.closed_loop import replay

    plant, amp, ss = _affine_models()
    pid = _pi(2000.0, 20.0)
    cl = assemble_closed_loop(plant, amp, ss, pid, pid)
    n = 1500
    t = np.arange(n) * DT
    arrays = {"t": t, "r_x": np.zeros(n), "r_y": np.zeros(n), "inj_x": np.where(t > 2e-3, 0.2, 0.0),
              "inj_y": np.zeros(n)}
    out = replay(cl, arrays)
    ref = simulate_closed_loop(cl, t, 0.0, 0.0, inj_x=arrays["inj_x"])
    np.testing.assert_array_equal(out["x_meas"], ref["x_meas"])
    assert nrmse_fit(ref["x_meas"], out["x_meas"]) == 100.0
    del arrays["inj_y"]
    replay(cl, arrays)  # optional columns
    with pytest.raises(ValueError, match="r_y"):
        replay(cl, {"t": t, "r_x": np.zeros(n)})


# --------------------------------------------------------------------------------------
# end to end: identify the three subsystems from closed-loop data of a known linear loop,
# assemble them with the real PID and replay held-out data
# --------------------------------------------------------------------------------------
def _known_linear_amb():
    """A linear stand-in for the AMB with the paper's structure (Fig. 3), discretised by ZOH.

    x: unstable rotor (negative stiffness), eddy-current sensor lag; y: a stable rotor (so that
    a self-sensing that only sees ``i_ypos`` can close the y loop, which no SISO LTI
    self-sensing can do for the unstable axis); amplifiers: first-order current loops with a
    position back-coupling; self-sensing: first-order low-pass of ``i_ypos`` about 3.57 A.
    Bias 3 A, gravity-like offset on y. The coil pairs are excited only differentially.
    """
    m, ks, kp, kn, kx = 3.86, 1.2e5, 22.0, 15.0, 18.4
    wsx, wa, wss, c, kss = 2 * np.pi * 2e4, 2 * np.pi * 2e3, 2 * np.pi * 2e3, 200.0, 1e-5
    A = np.zeros((5, 5))
    B = np.zeros((5, 5))  # states x, vx, x_sensor, y, vy; inputs CUR + one
    A[0, 1], A[1, 0], B[1, 2], B[1, 3] = 1, ks / m, kx / m, -kx / m
    A[2, 2], A[2, 0] = -wsx, wsx
    A[3, 4], A[4, 3], A[4, 4] = 1, -ks / m, -20.0
    B[4, 0], B[4, 1], B[4, 4] = kp / m, -kn / m, -(kp * 3.57 - kn * 2.43) / m
    C = np.zeros((2, 5))
    C[0, 2], C[1, 3] = 1, 1
    P = control.ss(A, B, C, 0, inputs=CUR + ["one"], outputs=["x_meas", "y_meas"])
    Ba = np.zeros((4, 5))
    Ba[0, 1], Ba[0, 3], Ba[1, 1], Ba[1, 3] = wa, -wa * c, -wa, wa * c
    Ba[2, 0], Ba[2, 2], Ba[3, 0], Ba[3, 2] = wa, -wa * c, -wa, wa * c
    Ba[:, 4] = 3 * wa
    G = control.ss(-wa * np.eye(4), Ba, np.eye(4), 0, inputs=["u_x_cmd", "u_y_cmd", "x_meas", "y_meas", "one"],
                   outputs=CUR)
    S = control.ss([[-wss]], [[wss * kss, -wss * kss * 3.57]], [[1.0]], 0, inputs=["i_ypos", "one"], outputs=["y_ss"])
    return [control.c2d(s, DT, "zoh") for s in (P, G, S)]


def _pulse_train(n, amp, seed):
    rng = np.random.default_rng(seed)
    out = np.zeros(n)
    i = 0
    while i < n:
        w = int(rng.integers(int(2e-4 * FS), int(4e-3 * FS)))
        out[i:i + w] = amp * rng.choice([-1.0, 0.0, 1.0])
        i += w
    return out


#: the paper's structures (4-input amplifier, current-input self-sensing): the known loop has them
PAPER = {"plant": "none", "amplifier": "full", "selfsensing": "current"}


@pytest.mark.slow
def test_identify_and_assemble_a_known_linear_loop():
    from ssamb.config import load_config
    from ssamb.identification import identify, nrmse_fit, subsystem_io
    from ssamb.closed_loop import replay
    from ssamb.sim.controller import pid_discrete

    pid = pid_discrete(load_config())
    truth = assemble_closed_loop(*_known_linear_amb(), pid, pid, require_stable=True)

    def experiment(duration_s, amp, seed):
        n = int(round(duration_s * FS))
        t = np.arange(n) * DT
        return simulate_closed_loop(truth, t, 0.0, 0.0, _pulse_train(n, amp, seed), _pulse_train(n, amp, seed + 1))

    est, val = experiment(0.1, 0.3, 1), experiment(0.05, 0.2, 3)
    models = {}
    # the amplifier: four current loops, but each pair's common-mode current is constant in these
    # data (the bias is fixed): at order 4 one mode is not determined by them and its eigenvalue
    # follows the rounding of the linear algebra (stable or not); order 3 is what they determine
    # (the validation page has both kernels' figures)
    for sub, order in (("plant", 5), ("amplifier", 3), ("selfsensing", 1)):
        u, y, ins, outs = subsystem_io(est, sub, PAPER[sub])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            models[sub] = identify(u, y, order, "N4SID", FS, ins, outs, ss_f=15, ss_p=15)
        if sub == "plant":  # the common-mode currents are constant (6 A per pair): not identifiable
            assert any("unexcited direction" in str(w.message) for w in caught)
    cl = assemble_closed_loop(models["plant"], models["amplifier"], models["selfsensing"], pid, pid,
                              require_stable=True)
    out = replay(cl, val)
    for col in ("x_meas", "y_meas", "y_ss", *CUR, "u_x", "u_y"):
        assert nrmse_fit(val[col], out[col]) > 99.5, col
    # the operating point (bias, gravity compensation) is reproduced without a start-up transient
    assert out["i_ypos"][0] == pytest.approx(val["i_ypos"][0], rel=1e-4)
    assert out["u_y"][0] == pytest.approx(val["u_y"][0], rel=1e-3)


# --------------------------------------------------------------------------------------
# the linear interconnection against python-control's
# --------------------------------------------------------------------------------------
def _random_subsystems(seed):
    """Random plant (order 3), amplifier with position inputs (order 2), self-sensing (order 1,
    affine) and PIDs with feedthrough: every block of Fig. 3 with states and cross terms."""
    rng = np.random.default_rng(seed)

    def ss(n, ins, outs, name, proper=False):
        A = 0.9 * rng.normal(size=(n, n)) / np.sqrt(n)
        D = np.zeros((len(outs), len(ins))) if not proper else rng.normal(size=(len(outs), len(ins)))
        return control.ss(A, rng.normal(size=(n, len(ins))), rng.normal(size=(len(outs), n)), D, DT,
                          inputs=ins, outputs=outs, name=name)

    plant = ss(3, CUR, ["x_meas", "y_meas"], "plant")
    amp = ss(2, ["u_x_cmd", "u_y_cmd", "x_meas", "y_meas"], CUR, "amplifier")
    sens = ss(1, ["y_meas", "one"], ["y_ss"], "selfsensing")
    return plant, amp, sens, ss(1, ["e"], ["u"], "pid_x", proper=True), ss(2, ["e"], ["u"], "pid_y", proper=True)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("variant", ["nominal", "open_x", "disturbed"])
def test_interconnect_linear_is_pythoncontrols(seed, variant):
    from ssamb.closed_loop import _junctions, _subsystems, interconnect_linear

    blocks = _subsystems(*_random_subsystems(seed)) + _junctions(DT, "x" if variant == "open_x" else None)
    ins = ["r_y", "inj_x", "inj_y", "one"] + (["e_x_in"] if variant == "open_x" else ["r_x"])
    outs = ["x_meas", "y_meas", "y_ss", "u_x", "i_ypos"]
    if variant == "disturbed":  # an additive input on the self-sensing output, as the generalized plant has
        sens = blocks[2]
        blocks[2] = control.ss(sens.A, sens.B, sens.C, sens.D, DT, inputs=sens.input_labels, outputs=["y_ss_nom"],
                               name="selfsensing")
        blocks.append(control.summing_junction(inputs=["y_ss_nom", "d_y_ss"], output="y_ss", dt=DT, name="add"))
        ins.append("d_y_ss")
    ref = control.interconnect(blocks, inplist=ins, inputs=ins, outlist=outs, outputs=outs, check_unused=False)
    for got, want in zip(interconnect_linear(blocks, ins, outs), (ref.A, ref.B, ref.C, ref.D)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
