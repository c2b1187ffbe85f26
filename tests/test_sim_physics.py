"""Physics of the nonlinear simulator against analytic laws (issue: simulator tests)."""
from __future__ import annotations

import math

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ssamb.config import apply_overrides, load_config
from ssamb.sim import amb_params, simulate
from ssamb.sim.controller import pid_discrete
from ssamb.sim.dsp import adc, pid_step, trend_basis
from ssamb.sim.eddy import fit_ladder, ladder_z, lamination_tau, lamination_z
from ssamb.sim.kernel import S_SIZE, S_VY, S_Y, _exp_neg, _rotor_step
from ssamb.sim.magnetics import MAX_PLAY, mmf, play_update, static_force
from ssamb.sim.params import MU0, P_GRAV

IDEAL_CONVERTERS = {"converters.current_noise_a": 0.0, "converters.current_adc_bits": 0,
                    "converters.position_noise_m": 0.0, "converters.position_adc_bits": 0}


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def _linear_cfg(cfg, **extra):
    ov = {"magnetics.saturation": False, "magnetics.hysteresis": False, "magnetics.eddy_currents": False,
          "magnetics.cross_coupling": False, **IDEAL_CONVERTERS}
    ov.update(extra)
    return apply_overrides(cfg, ov)


# ---------------------------------------------------------------------------------------------
# static magnetics
# ---------------------------------------------------------------------------------------------
def test_static_force_textbook_law(cfg):
    """F = mu0 N^2 A i^2 cos(alpha) / (4 g^2) at the centre (iron ideal, saturation off)."""
    c = _linear_cfg(cfg, **{"table1.mu_r": 1e12})
    par = amb_params(c)
    p = par.pack()
    n, a, g = par.turns, par.pole_area_m2, par.airgap_m
    for i in (0.5, 3.0, 5.0):
        expected = MU0 * n**2 * a * i**2 * math.cos(math.radians(22.5)) / (4 * g**2)
        assert static_force(p, i) == pytest.approx(expected, rel=1e-9)


def test_static_force_with_iron_reluctance(cfg):
    """With mu_r = 4000 the iron adds l_eq/mu_r to the two gaps: F = k i^2/(2g + l_eq/mu_r)^2."""
    par = amb_params(_linear_cfg(cfg))
    p = par.pack()
    for i, disp in ((3.0, 0.0), (3.6, 1e-4), (2.4, -1.5e-4)):
        assert static_force(p, i, disp) == pytest.approx(par.force_n(i, disp), rel=1e-9)


def test_ki_ks_finite_differences(cfg):
    """Current and position stiffness of the differential pair by finite differences."""
    par = amb_params(_linear_cfg(cfg))
    p = par.pack()
    i0 = par.i_bias_a

    def fnet(ic, y):
        return static_force(p, i0 + ic, y) - static_force(p, i0 - ic, -y)

    for ic in (0.0, 0.6):
        h_i, h_y = 1e-4, 1e-8
        ki_fd = (fnet(ic + h_i, 0.0) - fnet(ic - h_i, 0.0)) / (2 * h_i)
        ks_fd = (fnet(ic, h_y) - fnet(ic, -h_y)) / (2 * h_y)
        ki, ks = par.ki_ks(ic)
        assert ki_fd == pytest.approx(ki, rel=1e-6)
        assert ks_fd == pytest.approx(ks, rel=1e-5)


def test_saturation_flattens_force_above_knee(cfg):
    """Above the knee the force grows slower than i^2 and its slope collapses."""
    c_sat = apply_overrides(cfg, {"magnetics.hysteresis": False})
    c_lin = _linear_cfg(cfg)
    p_sat, p_lin = amb_params(c_sat).pack(), amb_params(c_lin).pack()
    # below the knee (B ~ 0.3 T at 3 A) saturation is invisible
    assert static_force(p_sat, 3.0) == pytest.approx(static_force(p_lin, 3.0), rel=1e-3)
    # B ~ 1.6-2 T: well above the 1.3 T knee
    i_hi = np.array([16.0, 18.0, 20.0])
    ratio = np.array([static_force(p_sat, i) / static_force(p_lin, i) for i in i_hi])
    assert ratio[0] < 0.9 and np.all(np.diff(ratio) < 0)
    slope_sat = (static_force(p_sat, 20.0) - static_force(p_sat, 18.0)) / 2.0
    slope_lin = (static_force(p_lin, 20.0) - static_force(p_lin, 18.0)) / 2.0
    assert slope_sat < 0.5 * slope_lin


def test_hysteresis_loop_area(cfg):
    """A symmetric B cycle of amplitude B_a gives the Prandtl-Ishlinskii loop area
    sum_k 4 w_k (B_a - r_k) (per unit volume and iron length) -- positive: energy is lost."""
    c = apply_overrides(cfg, {"magnetics.saturation": False, "magnetics.eddy_currents": False})
    par = amb_params(c)
    p = par.pack()
    ap = par.pole_area_m2
    gsum = 1.2e-3
    b_a = 0.8
    z = np.zeros(MAX_PLAY)
    bs = np.concatenate([np.linspace(0, b_a, 400), np.linspace(b_a, -b_a, 800), np.linspace(-b_a, b_a, 800)])
    hs = []
    for b in bs:
        play_update(b * ap, z, p)
        f, _ = mmf(b * ap, gsum, z, p)
        f_nohyst = b * ap * gsum / (MU0 * ap) + (
            par.l_pole_m * b / (MU0 * par.mu_r)
            + par.l_back_m * (b * ap / par.a_back_m2) / (MU0 * par.mu_r)
            + par.l_rotor_m * (b * ap / par.a_rotor_m2) / (MU0 * par.mu_r))
        hs.append((f - f_nohyst) / par.l_iron_total_m)   # the hysteresis field H_hy (A/m)
    hs = np.array(hs)
    # closed loop: descending B_a -> -B_a, then ascending -B_a -> B_a; the loop integral
    # int H dB = int (H_ascending - H_descending) dB is the energy lost per cycle
    area = np.trapezoid(hs[400:1200], bs[400:1200]) + np.trapezoid(hs[1200:], bs[1200:])
    k = np.arange(1, par.n_play + 1)
    r = par.play_width_max_t * k / par.n_play
    w = par.coercive_field_a_per_m / par.n_play
    expected = np.sum(4 * w * np.clip(b_a - r, 0, None))
    assert area > 0
    assert area == pytest.approx(expected, rel=0.02)


# ---------------------------------------------------------------------------------------------
# dynamics: PWM ripple, Faraday, eddy currents
# ---------------------------------------------------------------------------------------------
def _quiet(n):
    z = np.zeros(n)
    return {"r_x": z, "r_y": z}


def test_ripple_amplitude_and_frequency(cfg):
    """Ripple p-p = 2 V D (1 - D) T / L within 5 % and the current spectrum peaks at 30 kHz."""
    c = _linear_cfg(cfg, **{"simulation.substeps": 12})
    par = amb_params(c)
    n = int(0.02 * par.fs_hz)
    res = simulate(c, duration_s=0.02, arrays=_quiet(n), record_fine=True, track_ripple=True, settle_s=0.02)
    pp = res.ripple["i_max"] - res.ripple["i_min"]
    duty = res.data["duty_ypos"].mean()
    expected = par.ripple_pp_a(duty, res.data["y_true"].mean())
    assert np.median(pp) == pytest.approx(expected, rel=0.05)
    i = res.fine["i_ypos"]
    fs_fine = par.fs_hz * 12
    spec = np.abs(np.fft.rfft((i - i.mean()) * np.hanning(len(i))))
    f = np.fft.rfftfreq(len(i), 1 / fs_fine)
    band = f > 1000
    f_peak = f[band][np.argmax(spec[band])]
    assert f_peak == pytest.approx(par.f_pwm_hz, abs=2 * fs_fine / len(i))


def test_ripple_peak_resolution(cfg):
    """Switching edges are exact breakpoints: the ripple peak moves < 1 % at 10x finer steps
    (rotor clamped, amplifiers at the levitation currents with their PI loops: no feedback through
    the position, so both runs see the same PWM pattern; all physics on)."""
    c = apply_overrides(cfg, IDEAL_CONVERTERS)
    n = int(0.01 * cfg["controller"]["fs_hz"])
    u_y = simulate(c, duration_s=1e-3, arrays=_quiet(83), settle_s=0.0).meta["equilibrium"]["u_y"]
    runs = [simulate(c, duration_s=0.01, arrays={"inj_y": np.full(n, u_y)}, substeps=s, track_ripple=True,
                     settle_s=0.01, pid_on=False, clamp_m=(0.0, 0.0)) for s in (1, 10)]
    m = min(len(r.ripple["i_max"]) for r in runs)
    pc, pf = (r.ripple["i_max"][:m] - r.ripple["i_min"][:m] for r in runs)
    assert np.max(np.abs(pc - pf) / pf) < 0.01


def test_faraday_consistency(cfg):
    """v = R i + d(lambda)/dt along a run (all physics on): per sub-step,
    N (Phi_b - Phi_a) = int v dt - R int i dt."""
    c = apply_overrides(cfg, {"simulation.substeps": 8})       # converters in the loop: noise does not matter here
    par = amb_params(c)
    n = int(0.005 * par.fs_hz)
    res = simulate(c, duration_s=0.005, arrays=_quiet(n), record_fine=True, settle_s=0.005)
    h = 1.0 / (par.fs_hz * 8)
    for coil in ("ypos", "xneg"):
        phi = res.fine["phi_" + coil]
        i = res.fine["i_" + coil]
        v = res.fine["v_" + coil]
        lhs = par.turns * np.diff(phi)
        rhs = v[1:] * h - par.r_coil_ohm * 0.5 * (i[1:] + i[:-1]) * h
        assert np.max(np.abs(lhs - rhs)) < 1e-3 * np.max(np.abs(v)) * h


def _flux_lag_deg(c, f):
    """Lag (deg) of the ypos flux behind its current for a current command at ``f``, rotor clamped."""
    fs = c["controller"]["fs_hz"]
    n = int(0.02 * fs)
    t = np.arange(n) / fs
    res = simulate(c, duration_s=0.02, arrays={"inj_y": 0.3 * np.sin(2 * np.pi * f * t)}, record_fine=True,
                   settle_s=0.0, pid_on=False, clamp_m=(0.0, 0.0), start="levitated")
    keep = res.fine["t"] > 0.005
    ref = np.exp(-2j * np.pi * f * res.fine["t"][keep])
    ci = np.mean(res.fine["i_ypos"][keep] * ref)
    cphi = np.mean(res.fine["phi_ypos"][keep] * ref)
    return -np.degrees(np.angle(cphi / ci))


@pytest.mark.parametrize("model", ["ladder", "shorted_turn", "off"])
def test_eddy_current_flux_lag(cfg, model):
    """Eddy currents in the kernel: N i = (kappa + E(s)) Phi, so the flux lags the current by the
    angle of kappa + E(j w) -- E = g_e s for the shorted turn, R_fe (z_K(s) - 1) for the ladder."""
    c = apply_overrides(cfg, {"magnetics.saturation": False, "magnetics.hysteresis": False,
                              "magnetics.cross_coupling": False, "magnetics.eddy_currents": model != "off",
                              "magnetics.eddy_model": "ladder" if model == "off" else model,
                              "simulation.substeps": 4, **IDEAL_CONVERTERS})
    par = amb_params(c)
    kappa = par.turns**2 / par.inductance_h()           # small-signal reluctance (A/Wb)
    lags = []
    for f in (1000.0, 3000.0):
        w = 2 * np.pi * f
        if model == "ladder":
            extra = par.r_iron_a_per_wb * (ladder_z([f], par.ladder_weights, par.ladder_taus_s)[0] - 1.0)
        else:
            extra = 1j * w * par.eddy_conductance_s
        lag = _flux_lag_deg(c, f)
        assert lag == pytest.approx(np.degrees(np.angle(kappa + extra)), abs=0.3)
        lags.append(lag)
    if model != "off":
        assert lags[1] > lags[0] > 0.5
    else:
        assert abs(lags[0]) < 0.3


def test_eddy_ladder_matches_lamination_impedance(cfg):
    """The fitted ladder stays within 1 dB and 5 deg of the exact lamination solution
    z = sqrt(s tau) coth sqrt(s tau) from DC to 200 kHz -- on a grid the fit never saw -- and so
    does the coil impedance R + s N^2/(R_gap + R_fe z) it produces."""
    par = amb_params(cfg)
    mag = cfg["magnetics"]
    tau = lamination_tau(par.mu_r, mag["iron_conductivity_s_per_m"], mag["lamination_thickness_m"])
    f = np.linspace(0.0, 2.0e5, 4001)[1:]            # linear grid (the fit used a log grid)
    z = lamination_z(f, tau)
    zk = ladder_z(f, par.ladder_weights, par.ladder_taus_s)
    assert np.max(np.abs(20 * np.log10(np.abs(zk / z)))) < 1.0
    assert np.max(np.abs(np.degrees(np.angle(zk / z)))) < 5.0
    r_gap = 2 * par.airgap_m / (MU0 * par.pole_area_m2)
    s = 2j * np.pi * f
    coil = par.r_coil_ohm + s * par.turns**2 / (r_gap + par.r_iron_a_per_wb * np.stack([z, zk]))
    assert np.max(np.abs(20 * np.log10(np.abs(coil[1] / coil[0])))) < 1.0
    assert np.max(np.abs(np.degrees(np.angle(coil[1] / coil[0])))) < 5.0


def test_lamination_impedance_limits():
    """Exact lamination solution: 1 + s tau/3 at low frequency (the shorted turn's g_e) and
    sqrt(s tau) (skin effect, 45 deg) at high frequency."""
    tau = lamination_tau(4000.0, 2.0e6, 0.35e-3)
    assert tau == pytest.approx(4e-7 * np.pi * 4000 * 2e6 * 0.35e-3**2 / 4)
    f_lo = 1.0
    assert lamination_z([f_lo], tau)[0] == pytest.approx(1 + 2j * np.pi * f_lo * tau / 3, rel=1e-6)
    f_hi = 1.0e6
    x = np.sqrt(2j * np.pi * f_hi * tau)
    assert lamination_z([f_hi], tau)[0] == pytest.approx(x, rel=1e-9)
    # the fit is the exact expansion's first terms when asked for many sections at low frequency
    w, t = fit_ladder(tau, 3, 2.0e5)
    assert np.all(np.array(w) > 0) and t[0] > t[1] > t[2]


def test_contact_restitution(cfg):
    """A bounce on the backup bearing (the kernel's contact law, no other force) returns about
    half the impact speed, as the config states; measured at three impact speeds."""
    par = amb_params(cfg)
    p = par.pack()
    p[P_GRAV] = 0.0
    h = 1.0 / par.fs_hz / par.substeps
    for v0 in (0.01, 0.1, 1.0):
        st_ = np.zeros(S_SIZE)
        st_[S_Y] = -par.clearance_m + 1e-8
        st_[S_VY] = -v0
        for _ in range(100000):
            _rotor_step(st_, p, h, 0.0, 0.0, 0.0, 0.0)
            if st_[S_VY] > 0 and st_[S_Y] > -par.clearance_m:
                break
        assert 0.45 < st_[S_VY] / v0 < 0.55


# ---------------------------------------------------------------------------------------------
# controller and kernel helpers
# ---------------------------------------------------------------------------------------------
def test_kernel_pid_equals_tustin_pid(cfg):
    """The kernel's PID difference equation is the Tustin discretisation of the PID law."""
    par = amb_params(cfg)
    p = par.pack(UMAX=1e9)
    rng = np.random.default_rng(0)
    e = rng.normal(0, 1e-5, 400)
    stv = np.zeros(S_SIZE)
    u_kernel = np.array([pid_step.py_func(stv, p, 9, ek) for ek in e])
    sysd = pid_discrete(cfg)
    u_ref = control.forced_response(sysd, U=e).outputs
    assert np.allclose(u_kernel, u_ref, rtol=1e-9, atol=1e-12 * np.max(np.abs(u_ref)))


@given(v=st.floats(-12.0, 12.0), bits=st.integers(4, 16))
def test_adc_quantises_within_half_step_and_clips(v, bits):
    """A +/-10 A converter of ``bits`` bits: codes are multiples of q = 20/2^b, within q/2 of the
    input inside the range, clipped to the end codes outside."""
    q = 20.0 / 2**bits
    cmax = 2 ** (bits - 1) - 1
    out = adc.py_func(v, q, 1.0 / q, cmax)
    code = out / q
    assert code == pytest.approx(round(code), abs=1e-9)
    assert -cmax - 1 <= round(code) <= cmax
    if -10.0 + q < v < 10.0 - q:
        assert abs(out - v) <= q / 2 + 1e-12
    assert adc.py_func(v, 0.0, 0.0, 0.0) == v


@given(x=st.floats(0.0, 5.0))
def test_kernel_exp_matches_library(x):
    """The ladder's polynomial exp(-x) is the library's to 2e-11 relative (exact branch above 0.5)."""
    assert _exp_neg.py_func(x) == pytest.approx(math.exp(-x), rel=2e-11)


@given(w=st.integers(4, 40), order=st.integers(0, 3))
def test_trend_basis_orthonormal(w, order):
    tb = trend_basis(w, order)
    assert tb.shape == (order + 1, w)
    assert np.allclose(tb @ tb.T, np.eye(order + 1), atol=1e-10)


@settings(max_examples=60, deadline=None)
@given(phi=st.floats(-1.5e-3, 1.5e-3), gsum=st.floats(0.7e-3, 1.7e-3))
def test_mmf_monotonic_and_derivative(cfg, phi, gsum):
    """The MMF is increasing in the flux and dF/dphi is its derivative (no hysteresis)."""
    p = amb_params(apply_overrides(cfg, {"magnetics.hysteresis": False})).pack()
    z = np.zeros(MAX_PLAY)
    f, df = mmf(phi, gsum, z, p)
    h = 1e-9
    f2, _ = mmf(phi + h, gsum, z, p)
    f1, _ = mmf(phi - h, gsum, z, p)
    assert df > 0
    assert (f2 - f1) / (2 * h) == pytest.approx(df, rel=1e-4)


@settings(max_examples=40, deadline=None)
@given(bs=st.lists(st.floats(-1.5, 1.5), min_size=1, max_size=30))
def test_play_states_stay_within_width(cfg, bs):
    par = amb_params(cfg)
    p = par.pack()
    z = np.zeros(MAX_PLAY)
    for b in bs:
        play_update(b * par.pole_area_m2, z, p)
        r = par.play_width_max_t * np.arange(1, par.n_play + 1) / par.n_play
        assert np.all(np.abs(b - z[: par.n_play]) <= r + 1e-12)
