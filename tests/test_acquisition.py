"""Tests of the logging chain's anti-alias filter (``ssamb.acquisition``).

The filter's response is checked against the analytic Butterworth response, not against
SciPy's own evaluation of the designed filter: the gain and phase of a sine after the filter
(fitted by least squares) against

    H(f) = prod_k 1 / (j w - p_k),  p_k = exp(j pi (2k + n - 1) / (2n)),  |H| = 1 / sqrt(1 + w^(2n)),

with w = tan(pi f / fs) / tan(pi fc / fs), the frequency the bilinear transform with a
prewarped cutoff maps f to (w = f / fc at f = fc, where the test's first frequency sits).
"""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from ssamb.acquisition import ANALOG_CHANNELS, apply_acquisition, validate_acquisition
from ssamb.errors import InputError

FS_HZ = 83300.0
DIGITAL = ("y_ss", "u_x", "u_y", "r_x", "r_y", "inj_x", "inj_y")


def analytic_butterworth(f_hz: float, fc_hz: float, order: int, fs_hz: float) -> complex:
    """The analog Butterworth low-pass at the bilinear transform's warped frequency."""
    w = math.tan(math.pi * f_hz / fs_hz) / math.tan(math.pi * fc_hz / fs_hz)
    poles = [np.exp(1j * math.pi * (2 * k + order - 1) / (2 * order)) for k in range(1, order + 1)]
    h = 1.0 / np.prod([1j * w - p for p in poles])
    assert abs(abs(h) - 1.0 / math.sqrt(1.0 + w ** (2 * order))) < 1e-12    # the two forms agree
    return complex(h)


def fitted_sine(x: np.ndarray, f_hz: float, fs_hz: float) -> complex:
    """Complex amplitude a of x ~ Re(a exp(j 2 pi f t)), by least squares."""
    t = np.arange(x.size) / fs_hz
    basis = np.column_stack([np.cos(2 * math.pi * f_hz * t), -np.sin(2 * math.pi * f_hz * t)])
    (re, im), *_ = np.linalg.lstsq(basis, x, rcond=None)
    return complex(re, im)


@pytest.mark.parametrize("order", [2, 4])
@pytest.mark.parametrize("ratio", [1.0, 2.0])
def test_gain_and_phase_are_the_analytic_butterworth_response(order, ratio):
    fc = 5000.0
    f = ratio * fc
    n = 20000
    x = np.sin(2 * math.pi * f * np.arange(n) / FS_HZ)
    y = apply_acquisition({"x_meas": x}, {"antialias_hz": fc, "order": order}, FS_HZ)["x_meas"]
    skip = 2000                                    # the start-up transient (decays within ~1 ms)
    measured = fitted_sine(y[skip:], f, FS_HZ) / fitted_sine(x[skip:], f, FS_HZ)
    expected = analytic_butterworth(f, fc, order, FS_HZ)
    assert abs(abs(measured) / abs(expected) - 1) < 1e-4
    assert abs(np.angle(measured / expected)) < 1e-4
    if ratio == 1.0:      # at the cutoff: -3 dB and -n 45 deg, the analog values exactly
        assert abs(abs(measured) - 1 / math.sqrt(2)) < 1e-4
        assert abs(np.angle(measured * np.exp(1j * order * math.pi / 4))) < 1e-4


def test_only_the_analog_channels_are_filtered_and_inputs_untouched():
    rng = np.random.default_rng(1)
    chans = {c: rng.standard_normal(4000) for c in ANALOG_CHANNELS + DIGITAL + ("t",)}
    before = {c: v.copy() for c, v in chans.items()}
    out = apply_acquisition(chans, {"antialias_hz": 2000.0, "order": 4}, FS_HZ)
    assert set(out) == set(chans) and out is not chans
    for c in ANALOG_CHANNELS:
        assert np.std(out[c]) < 0.4 * np.std(chans[c]), c          # white noise: mostly above 2 kHz
    for c in DIGITAL + ("t",):
        assert out[c] is chans[c], c
    for c in chans:
        np.testing.assert_array_equal(chans[c], before[c])         # pure: the inputs unchanged
    again = apply_acquisition(chans, {"antialias_hz": 2000.0, "order": 4}, FS_HZ)
    for c in ANALOG_CHANNELS:
        np.testing.assert_array_equal(again[c], out[c])            # deterministic


@pytest.mark.parametrize("spec", [None, {}])
def test_no_specification_is_no_filter(spec):
    x = np.linspace(0.0, 1.0, 100)
    out = apply_acquisition({"y_meas": x}, spec, FS_HZ)
    assert out["y_meas"] is x and validate_acquisition(spec, "f") == {}


def test_a_record_starts_without_a_filter_transient():
    x = np.full(3000, 2.5e-5)                  # a rotor resting off-centre, logged from t = 0
    y = apply_acquisition({"y_meas": x, "i_ypos": x + 3.0}, {"antialias_hz": 1000.0, "order": 8}, FS_HZ)
    np.testing.assert_allclose(y["y_meas"], x, rtol=1e-9, atol=0)
    np.testing.assert_allclose(y["i_ypos"], x + 3.0, rtol=1e-12, atol=0)


def test_order_defaults_to_4_and_is_normalised():
    assert validate_acquisition({"antialias_hz": 10000}, "f", FS_HZ) == {"antialias_hz": 10000.0, "order": 4}


@pytest.mark.parametrize("spec, key", [
    ({"antialias_hz": 0.0}, "acquisition.antialias_hz"),
    ({"antialias_hz": 41650.0}, "acquisition.antialias_hz"),
    ({"antialias_hz": float("nan")}, "acquisition.antialias_hz"),
    ({"antialias_hz": "10k"}, "acquisition.antialias_hz"),
    ({"order": 4}, "acquisition.antialias_hz"),
    ({"antialias_hz": 1e4, "order": 0}, "acquisition.order"),
    ({"antialias_hz": 1e4, "order": 9}, "acquisition.order"),
    ({"antialias_hz": 1e4, "order": 4.0}, "acquisition.order"),
    ({"antialias_hz": 1e4, "order": True}, "acquisition.order"),
    ({"antialias_hz": 1e4, "type": "bessel"}, "acquisition.type"),
    ([1e4, 4], "acquisition"),
])
def test_bad_specifications_name_the_key(spec, key):
    with pytest.raises(InputError, match="^" + re.escape(f"rig.yaml: key '{key}': ")) as exc:
        validate_acquisition(spec, "rig.yaml", FS_HZ)
    assert "\n" not in str(exc.value)
