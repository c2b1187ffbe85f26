"""Augmented model and sweep-validation helpers (paper section 6.1)."""
import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ssamb.validation import (augment_subsystem, critical_amplitude_bisect, critical_amplitude_lti,
                              delta_system, first_contact)

DT = 1 / 83300.0


def _affine_static(gain, offset):
    """y = gain * u + offset * one, discrete, no states."""
    return control.ss(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), [[gain, offset]], DT,
                      inputs=["i_ypos", "one"], outputs=["y_ss"], name="ss")


@pytest.mark.parametrize("delta, sign", [("plus", 1.0), ("minus", -1.0)])
def test_augmented_adds_weighted_deviation(delta, sign):
    model = _affine_static(2e-5, -7e-5)
    w = control.tf([0.0, 3e-6], [1.0])            # constant weight 3e-6 m/A (proper, for the test)
    aug = augment_subsystem(model, control.ss(w), "i_ypos", "y_ss", u_op=3.6, delta=delta)
    u = np.array([3.6, 3.7, 3.1])
    yn = 2e-5 * u - 7e-5
    assert aug.nstates == 0
    ya = [(np.asarray(aug.D) @ np.array([ui, 1.0])).item() for ui in u]
    assert np.allclose(ya, yn + sign * 3e-6 * (u - 3.6), rtol=1e-12, atol=1e-15)


def test_augmented_operating_point_unchanged_with_dynamic_weight():
    model = _affine_static(2e-5, -7e-5)
    s = control.tf("s")
    w = 1e-6 * (s / 100 + 1) / (s / 1e4 + 1) ** 2  # strictly proper? (degree 1 / 2): yes
    aug = augment_subsystem(model, w, "i_ypos", "y_ss", u_op=3.6, delta="allpass")
    # DC gain from 'one' with i_ypos = u_op must equal the nominal set point
    dc = control.dcgain(aug)
    assert dc[0, 0] * 3.6 + dc[0, 1] == pytest.approx(2e-5 * 3.6 - 7e-5, rel=1e-9)


@settings(max_examples=20, deadline=None)
@given(f=st.floats(1.0, 20000.0), fa=st.floats(1.0, 1000.0))
def test_allpass_has_unit_gain(f, fa):
    d = delta_system("allpass", DT, fa)
    z = np.exp(2j * np.pi * f * DT)
    assert abs(d(z)) == pytest.approx(1.0, rel=1e-9)


def test_first_contact():
    t = np.linspace(0, 1, 1001)
    x = 1e-4 * np.sin(2 * np.pi * 3 * t) * t * 4
    tc = first_contact(t, x, 0 * x, 2.5e-4)
    assert tc is not None and np.hypot(x, 0)[np.searchsorted(t, tc)] >= 2.5e-4
    assert first_contact(t, 0.5 * 1e-4 + 0 * t, 0 * t, 2.5e-4) is None


def test_critical_amplitude_lti_sine():
    t = np.linspace(0, 1, 5000)
    px = 0 * t
    py = 1.7 * np.sin(2 * np.pi * 10 * t)       # |T| = 1.7 per metre of reference amplitude
    a = critical_amplitude_lti(px, py, 0.0, 0.0, 2.5e-4)
    assert a == pytest.approx(2.5e-4 / 1.7, rel=1e-3)
    # an operating offset towards the bearing lowers the critical amplitude
    assert critical_amplitude_lti(px, py, 0.0, 5e-5, 2.5e-4) == pytest.approx(2.0e-4 / 1.7, rel=1e-3)


def test_bisection_finds_threshold():
    res = critical_amplitude_bisect(lambda a: a >= 1.234e-4, 1e-5, 3e-4, rel_tol=1e-3)
    assert res["amplitude_m"] == pytest.approx(1.234e-4, rel=2e-3)
    assert critical_amplitude_bisect(lambda a: False, 1e-5, 3e-4)["amplitude_m"] is None


def test_bisection_below_its_lower_end_walks_down_instead_of_reporting_that_end():
    """A threshold under the bracket's lower end is found (the end is halved until the model
    levitates), not reported as the end itself; one under the whole search is None, flagged."""
    res = critical_amplitude_bisect(lambda a: a >= 2.0e-5, 6.25e-5, 5e-4, rel_tol=1e-3)
    assert res["amplitude_m"] == pytest.approx(2.0e-5, rel=2e-3) and not res["below_search"]
    low = critical_amplitude_bisect(lambda a: a >= 1e-7, 6.25e-5, 5e-4)
    assert low["amplitude_m"] is None and low["below_search"]
    assert low["bracket"] == [0.0, pytest.approx(6.25e-5 / 16)]
