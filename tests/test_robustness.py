"""Tests of the generic robustness helpers ``ssamb.robustness`` (analytic expectations)."""
import control
import numpy as np
import pytest

from ssamb.robustness import (
    ISO14839_LIMITS,
    loop_margins,
    frequency_response_matrix,
    iso14839_zone,
    mu_frequency_response,
    sensitivity_peak,
)

ZETA = 0.1
WN = 2 * np.pi * 3.0  # 3 Hz resonance


def n11_siso(f):
    s = 2j * np.pi * f
    return np.array([[WN**2 / (s**2 + 2 * ZETA * WN * s + WN**2)]])


# analytic resonance peak of a second-order low pass
PEAK = 1.0 / (2 * ZETA * np.sqrt(1 - ZETA**2))
PEAK_HZ = WN * np.sqrt(1 - 2 * ZETA**2) / (2 * np.pi)


def test_mu_of_siso_loop_equals_modulus_and_refined_peak():
    freqs = np.geomspace(0.1, 100, 40)
    sw = mu_frequency_response(n11_siso, freqs, [[1, 1]])
    mags = np.array([abs(n11_siso(f)[0, 0]) for f in sw.freqs_hz])
    np.testing.assert_allclose(sw.upper, mags, rtol=1e-12)
    np.testing.assert_allclose(sw.lower, mags, rtol=1e-12)
    assert sw.peak == pytest.approx(PEAK, rel=1e-9)
    assert sw.peak_hz == pytest.approx(PEAK_HZ, rel=1e-4)
    assert sw.margin == pytest.approx(1 / PEAK)
    assert sw.margin_difference == pytest.approx(1 - PEAK)
    assert sw.scale_for_unity == pytest.approx(1 / PEAK)
    # the coarse grid alone misses the peak
    coarse = mu_frequency_response(n11_siso, freqs, [[1, 1]], refine=False)
    assert coarse.peak < PEAK * (1 - 1e-3)


def test_weight_scaling_is_linear_and_scale_for_unity_brings_peak_to_one():
    """Additive W*Delta: N11 = W*T, so mu scales linearly with W."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((3, 3)) + 1j * rng.standard_normal((3, 3))

    def n11(f, k=1.0):
        return k * A / (1 + 1j * f)

    freqs = np.linspace(0.0, 5.0, 11)
    blk = [[1, 1], [2, 2]]
    base = mu_frequency_response(n11, freqs, blk)
    for k in (0.0012, 3.0):
        sc = mu_frequency_response(lambda f: n11(f, k), freqs, blk)
        assert sc.peak == pytest.approx(k * base.peak, rel=1e-5)
        assert sc.scale_for_unity == pytest.approx(base.scale_for_unity / k, rel=1e-5)
    unity = mu_frequency_response(lambda f: n11(f, base.scale_for_unity), freqs, blk)
    assert unity.peak == pytest.approx(1.0, rel=1e-5)
    assert unity.margin_difference == pytest.approx(0.0, abs=1e-5)


def test_array_input_and_lti_input():
    sysc = control.tf([WN**2], [1, 2 * ZETA * WN, WN**2])
    freqs = np.geomspace(0.5, 20, 25)
    resp = frequency_response_matrix(sysc, freqs)
    sw = mu_frequency_response(resp, freqs, [[1, 1]])
    np.testing.assert_allclose(sw.upper, np.abs(resp[:, 0, 0]), rtol=1e-12)
    assert sw.peak <= PEAK
    sw_lti = mu_frequency_response(sysc, freqs, [[1, 1]])
    assert sw_lti.peak == pytest.approx(PEAK, rel=1e-9)
    with pytest.raises(ValueError):
        mu_frequency_response(resp[:-1], freqs, [[1, 1]])


def test_frequency_response_matrix_continuous_and_discrete():
    sys = control.ss([[-1.0, 2.0], [0.0, -3.0]], [[1.0, 0.0], [0.0, 1.0]],
                     [[1.0, 1.0], [0.0, 2.0], [1.0, 0.0]], np.zeros((3, 2)))
    freqs = np.array([0.0, 0.1, 1.0, 10.0])
    H = frequency_response_matrix(sys, freqs)
    assert H.shape == (4, 3, 2)
    A, B, C, D = (np.asarray(x) for x in (sys.A, sys.B, sys.C, sys.D))
    for f, Hf in zip(freqs, H):
        ref = C @ np.linalg.solve(2j * np.pi * f * np.eye(2) - A, B) + D
        np.testing.assert_allclose(Hf, ref, rtol=1e-10, atol=1e-12)
    dt = 1e-3
    sysd = control.tf([0.5, 0.1], [1.0, -0.7], dt)
    fd = np.array([1.0, 50.0, 400.0])
    Hd = frequency_response_matrix(sysd, fd)
    z = np.exp(2j * np.pi * fd * dt)
    np.testing.assert_allclose(Hd[:, 0, 0], (0.5 * z + 0.1) / (z - 0.7), rtol=1e-10)


def test_iso14839_zone_boundaries():
    assert ISO14839_LIMITS == {"A": 3.0, "B": 4.0, "C": 5.0}
    assert iso14839_zone(1.0) == "A"
    assert iso14839_zone(2.999) == "A"
    assert iso14839_zone(3.0) == "B"
    assert iso14839_zone(10 ** (9.6 / 20)) == "B"  # 9.6 dB
    assert iso14839_zone(3.999) == "B"
    assert iso14839_zone(4.0) == "C"
    assert iso14839_zone(10 ** (13.9 / 20)) == "C"  # 13.9 dB
    assert iso14839_zone(5.0) == "D"
    assert iso14839_zone(100.0) == "D"
    # the dB figures quoted for the boundaries
    assert 20 * np.log10(3) == pytest.approx(9.5, abs=0.05)
    assert 20 * np.log10(4) == pytest.approx(12.0, abs=0.05)
    assert 20 * np.log10(5) == pytest.approx(14.0, abs=0.05)
    for bad in (-1.0, np.nan, np.inf):
        with pytest.raises(ValueError):
            iso14839_zone(bad)


def test_sensitivity_peak_of_second_order_loop():
    """L = wn^2 / (s (s + 2 zeta wn)): S = s(s + 2 zeta wn) / (s^2 + 2 zeta wn s + wn^2)."""
    L = control.tf([WN**2], [1, 2 * ZETA * WN, 0])
    S = control.feedback(1, L)
    # analytic |S(jw)|^2 = w^2 (w^2 + 4 z^2 wn^2) / ((wn^2 - w^2)^2 + 4 z^2 wn^2 w^2):
    # maximise over a very dense grid of the closed form
    w = np.linspace(0.01, 20, 2_000_001) * WN
    mag = np.sqrt(w**2 * (w**2 + 4 * ZETA**2 * WN**2)
                  / ((WN**2 - w**2) ** 2 + 4 * ZETA**2 * WN**2 * w**2))
    k = np.argmax(mag)
    freqs = np.geomspace(0.1, 100, 60)
    for sys, kind in ((S, "S"), (L, "L")):
        pk = sensitivity_peak(sys, freqs, kind=kind)
        assert pk.peak == pytest.approx(mag[k], rel=1e-8)
        assert pk.peak_hz == pytest.approx(w[k] / (2 * np.pi), rel=1e-4)
        assert pk.peak_db == pytest.approx(20 * np.log10(mag[k]), rel=1e-8)
        assert pk.zone == iso14839_zone(mag[k]) == "D"  # zeta = 0.1 is lightly damped
    # array input (no refinement) and callable input
    resp = frequency_response_matrix(S, freqs)
    assert sensitivity_peak(resp, freqs).peak <= mag[k] * (1 + 1e-12)
    pk = sensitivity_peak(lambda f: frequency_response_matrix(L, [f])[0], freqs, kind="L")
    assert pk.peak == pytest.approx(mag[k], rel=1e-8)


def test_loop_margins_of_a_known_loop():
    """L = 2/(s+1)^3: gain margin 4 (12.04 dB) at w = sqrt(3); phase margin from |L| = 1."""
    s = control.tf("s")
    L = 2 / (s + 1) ** 3
    m = loop_margins(L, np.logspace(-2, 1, 200000) / (2 * np.pi))
    assert m["gain_margin_upper_db"] == pytest.approx(20 * np.log10(4), abs=1e-3)
    assert m["gain_margin_upper_hz"] == pytest.approx(np.sqrt(3) / (2 * np.pi), rel=1e-4)
    wc = np.sqrt(2 ** (2 / 3) - 1)
    assert m["phase_margin_deg"] == pytest.approx(180 - 3 * np.degrees(np.arctan(wc)), abs=1e-3)
    assert m["gain_margin_lower_db"] is None


def test_loop_margins_of_an_unstable_open_loop():
    """PID on an unstable plant, L = (2 s^2 + 4 s + 1)/(s (s^2 - 1)).

    Closed loop for a gain k: s^3 + 2k s^2 + (4k - 1) s + k; Routh: stable iff k > 3/8. So the
    loop tolerates a gain reduction to 3/8 (-8.52 dB) and any increase (no upper margin).
    """
    s = control.tf("s")
    L = (2 * s**2 + 4 * s + 1) / (s * (s**2 - 1))
    m = loop_margins(L, np.logspace(-3, 3, 400000) / (2 * np.pi))
    assert m["gain_margin_lower_db"] == pytest.approx(20 * np.log10(3 / 8), abs=1e-3)
    assert m["gain_margin_upper_db"] is None
    assert m["phase_margin_deg"] > 0
