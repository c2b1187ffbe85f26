"""The levitated ball's model: force law, equilibrium, the coil's RL response, stops, ADCs."""
import math

import numpy as np
import pytest

from ssamb.maglev1d import physics as P
from ssamb.maglev1d.config import default_config
from ssamb.maglev1d.controller import gains_of

CFG = default_config()


def _knobs(**kw):
    return P.knobs_of(CFG, kw)


def test_force_is_half_i2_dl_dy():
    k0, k, a = 0.07, 0.033, 0.005
    y = np.linspace(0.0, 0.02, 9)
    h = 1e-8
    dldy = (P.inductance_h(y + h, k0, k, a) - P.inductance_h(y - h, k0, k, a)) / (2 * h)
    np.testing.assert_allclose(P.force_n(y, 0.6, k, a), 0.5 * 0.36 * np.abs(dldy), rtol=1e-6)


def test_equilibrium_current_balances_weight_in_the_kernel():
    p = _knobs()
    m, g = CFG["ball"]["mass_kg"], CFG["ball"]["gravity_m_per_s2"]
    for y in (0.003, 0.005, 0.008):
        i = float(P.equilibrium_current_a(y, m, g, CFG["magnet"]["k_h"], CFG["magnet"]["a_m"]))
        dy, dv, di = P._deriv(p, y, 0.0, i, (CFG["coil"]["r_ohm"] + CFG["coil"]["r_shunt_ohm"]) * i,
                              p[P.R], 0.0, 0)
        assert abs(dv) < 1e-9 and abs(di) < 1e-9


def _coil_run(p, v, t_end, i0=0.0, y0=None, mode=2):
    """Integrate the coil alone (ball held on a stop) at a constant voltage."""
    st = np.array([p[P.YBOT] if y0 is None else y0, 0.0, i0, float(mode)])
    h = 1e-4
    out = []
    for _ in range(int(round(t_end / h))):
        P._rk4(p, st, v, p[P.R], 1e3, h)           # a large downward force keeps it on the stop
        out.append(st[2])
    return np.array(out), h


def test_coil_rl_step_response():
    p = _knobs()
    r = p[P.R]
    ind = float(P.inductance_h(p[P.YBOT], p[P.K0], p[P.K], p[P.A]))
    i, h = _coil_run(p, 5.0, 0.1)
    t = h * np.arange(1, len(i) + 1)
    np.testing.assert_allclose(i, 5.0 / r * (1 - np.exp(-t * r / ind)), rtol=1e-6, atol=1e-9)


def test_eddy_branch_slows_the_flux_and_makes_the_terminal_current_jump():
    tau_e = 2e-3
    p = _knobs(eddy_tau_s=tau_e)
    r = p[P.R]
    ind = float(P.inductance_h(p[P.YBOT], p[P.K0], p[P.K], p[P.A]))
    im, h = _coil_run(p, 5.0, 0.1)
    t = h * np.arange(1, len(im) + 1)
    # the flux current's time constant is (L + R tau_e)/R
    np.testing.assert_allclose(im, 5.0 / r * (1 - np.exp(-t * r / (ind + r * tau_e))), rtol=1e-6, atol=1e-9)
    # at switch-on the terminal current jumps by tau_e v / (L + R tau_e)
    assert P._terminal(p, p[P.YBOT], 0.0, 5.0, r) == pytest.approx(tau_e * 5.0 / (ind + r * tau_e))


def test_motion_term_back_emf():
    """d(L i)/dt = v - R i: with i constant the motion term is -i dL/dy dy/dt."""
    p = _knobs()
    y, vel, i = 0.005, 0.1, 0.4
    s = 1 + y / p[P.A]
    dldy = -p[P.K] / (p[P.A] * s * s)
    ind = p[P.K0] + p[P.K] / s
    _, _, di = P._deriv(p, y, vel, i, p[P.R] * i, p[P.R], 0.0, 0)
    assert di == pytest.approx(-i * dldy * vel / ind)


def test_free_fall_onto_the_lower_stop_and_rest():
    p = _knobs()
    st = np.array([0.002, 0.0, 0.0, 0.0])
    h = 1e-4
    t = 0.0
    while st[3] == 0.0:
        P._rk4(p, st, 0.0, p[P.R], 0.0, h)
        t += h
    drop = p[P.YBOT] - 0.002
    assert t == pytest.approx(math.sqrt(2 * drop / p[P.G]), abs=2 * h)
    assert st[3] == 2.0 and st[0] == p[P.YBOT] and st[1] == 0.0


def test_stuck_to_the_magnet_releases_when_the_force_drops_below_the_weight():
    p = _knobs()
    m, g, k, a = p[P.M], p[P.G], p[P.K], p[P.A]
    i_hold = math.sqrt(2 * a * m * g / k)             # F(0, i) = m g
    ind0 = p[P.K0] + k
    st = np.array([0.0, 0.0, 2 * i_hold, 1.0])
    h = 1e-5
    t = 0.0
    while st[3] == 1.0:
        P._rk4(p, st, 0.0, p[P.R], 0.0, h)
        t += h
    # with no voltage the current decays from 2 i_hold with L(0)/R: released at i = i_hold
    assert t == pytest.approx(ind0 / p[P.R] * math.log(2.0), abs=3 * h)


def test_restitution_rebound():
    p = _knobs()
    p[P.REST] = 0.5
    st = np.array([p[P.YBOT] - 1e-6, 0.5, 0.0, 0.0])
    P._rk4(p, st, 0.0, p[P.R], 0.0, 1e-4)
    assert st[0] == p[P.YBOT] and st[1] == pytest.approx(-0.5 * (0.5 + p[P.G] * 1e-4), rel=1e-3) and st[3] == 0.0


def test_adc_rounds_to_the_nearest_count_and_clips():
    q = 0.05 / 1023
    assert P._adc(10.49 * q, q, 1023.0, 0.0, 0.3) == pytest.approx(10 * q)
    assert P._adc(10.51 * q, q, 1023.0, 0.0, -0.3) == pytest.approx(11 * q)
    assert P._adc(-3 * q, q, 1023.0, 0.0, 0.0) == 0.0
    assert P._adc(2000 * q, q, 1023.0, 0.0, 0.0) == pytest.approx(1023 * q)


def test_additive_adc_adds_its_draw_and_clips():
    q = 0.05 / 1023
    assert P._adc(10.3 * q, q, 1023.0, 1.0, 0.2) == pytest.approx(10.5 * q)
    assert P._adc(10.3 * q, q, 1023.0, 1.0, -0.5) == pytest.approx(9.8 * q)
    assert P._adc(-3 * q, q, 1023.0, 1.0, 0.4) == 0.0
    assert P._adc(2000 * q, q, 1023.0, 1.0, -0.4) == pytest.approx(1023 * q)


def test_pwm_duty_truncates_to_its_steps_and_clips():
    p = _knobs()
    p[P.QADD] = 0.0
    step = p[P.VREF] / p[P.NPWM]
    assert P._amplifier(p, 10.7 * step, 0.4) == pytest.approx(10 * step * p[P.VMAX] / p[P.VREF])
    assert P._amplifier(p, 1e3, 0.0) == pytest.approx(p[P.VMAX])
    assert P._amplifier(p, -1.0, 0.0) == 0.0
    p[P.VDROP] = 1.2
    assert P._amplifier(p, 1e3, 0.0) == pytest.approx(p[P.VMAX] - 1.2)


def test_additive_pwm_keeps_the_truncations_mean():
    """The additive duty is the command less half a step plus the draw: over uniform draws its
    mean is the truncation's mean over a uniformly spread command, :math:`u - 1/2` step."""
    p = _knobs()
    p[P.QADD] = 1.0
    step = p[P.VREF] / p[P.NPWM]
    gain = p[P.VMAX] / p[P.VREF]
    assert P._amplifier(p, 10.7 * step, 0.1) == pytest.approx(10.3 * step * gain)
    draws = np.linspace(-0.5, 0.5, 1001)[:-1] + 0.0005
    mean_add = np.mean([P._amplifier(p, 10.7 * step, d) for d in draws])
    p[P.QADD] = 0.0
    mean_trunc = np.mean([P._amplifier(p, (10.0 + f) * step, 0.0) for f in np.linspace(0, 1, 1001)[:-1] + 0.0005])
    assert mean_add == pytest.approx((10.7 - 0.5) * step * gain, rel=1e-9)
    assert mean_trunc == pytest.approx(10.0 * step * gain, rel=1e-9)
    assert P._amplifier(p, 1e3, 0.0) == pytest.approx(p[P.VMAX])


def test_simulation_holds_a_ball_at_equilibrium_and_is_deterministic():
    """An adjusted stage (half the voltage) makes the sampled loop stable; the ball released at
    the reference with its equilibrium current stays levitated within a few counts."""
    cfg = default_config()
    cfg["amplifier"]["v_max_v"] = 4.85
    p = P.knobs_of(cfg)
    g = gains_of(cfg)
    n = 500
    yd = np.full(n, 0.005)
    m, gg = cfg["ball"]["mass_kg"], cfg["ball"]["gravity_m_per_s2"]
    i0 = float(P.equilibrium_current_a(0.005, m, gg, cfg["magnet"]["k_h"], cfg["magnet"]["a_m"]))
    r = cfg["coil"]["r_ohm"] + cfg["coil"]["r_shunt_ohm"]
    u0 = r * i0 / (4.85 / 9.86)
    init = np.array([[0.005, 0.0, i0, 0.0, -i0, u0 - 0.0, u0]])
    noise = np.random.default_rng(3).standard_normal((3, n))
    a = P.simulate(p, g, yd, [(0, n)], init, noise)
    b = P.simulate(p, g, yd, [(0, n)], init, noise)
    assert not a["contact"].any()
    assert np.max(np.abs(a["y"] - 0.005)) < 10 * 0.05 / 1023
    for c in ("y", "i", "u"):
        np.testing.assert_array_equal(a[c], b[c])


def test_sensor_curvature_reading_and_its_inverse():
    """reading = l + q (l - c)^2 with l = g y + o: neutral at q = 0, unchanged at the centre, the
    inverse recovers y on the monotonic branch, and the local scale is the derivative."""
    y = np.linspace(0.0, 0.018, 37)
    p0 = _knobs(sensor_gain=0.8, sensor_offset_m=0.001)
    np.testing.assert_allclose(P.reading_m(p0, y), 0.8 * y + 0.001 * 1 + CFG["sensors"]["position_offset_m"])
    p = _knobs(sensor_gain=0.8, sensor_offset_m=0.001, sensor_curvature_per_m=25.0)
    r = P.reading_m(p, y)
    np.testing.assert_allclose(P.position_m(p, r), y, atol=1e-12)
    yc = (p[P.knob_index("sensor_centre_m")] - 0.001) / 0.8
    assert float(P.reading_m(p, yc)) == pytest.approx(float(P.reading_m(p0, yc)), abs=1e-15)
    h = 1e-7
    num = (P.reading_m(p, y + h) - P.reading_m(p, y - h)) / (2 * h)
    np.testing.assert_allclose(P.reading_slope(p, y), num, rtol=1e-6)
    assert np.all(np.diff(r) > 0)


def test_curved_sensor_in_the_kernel_reads_the_same_function():
    """A ball held at rest reads the curved sensor's value (no noise, a fine ADC)."""
    p = _knobs(sensor_curvature_per_m=40.0)
    p[P.knob_index("position_lsb_m")] = 1e-9
    p[P.knob_index("position_counts")] = 1e9
    y0, i0, u0 = P.equilibrium(p, 0.0065)
    init = np.array([[y0, 0.0, i0, 0.0, -i0, u0, u0]])
    out = P.simulate(p, gains_of(CFG), np.full(3, 0.0065), [(0, 3)], init, None)
    assert out["y"][0] == pytest.approx(0.0065, abs=2e-9)
    assert float(P.reading_m(p, y0)) == pytest.approx(0.0065, abs=1e-12)
