"""Tests of ssamb.signals: analytic properties of every excitation, exact where they can be."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from ssamb import signals as sg

FS = 83_300.0


# --------------------------------------------------------------------------------- multisine
def test_multisine_paper_case_lines_amplitude_periodicity():
    ms = sg.multisine(FS, 1e-4, 5.0, 26.0, 1.0, 4, seed=3)
    n = ms.samples_per_period
    assert n == 83_300
    np.testing.assert_array_equal(ms.lines_hz, np.arange(5.0, 27.0))
    np.testing.assert_array_equal(ms.lines_bins, np.arange(5, 27))
    assert ms.x.dtype == np.float64 and ms.x.size == 4 * n and ms.t.size == 4 * n
    np.testing.assert_allclose(ms.t[1] - ms.t[0], 1 / FS)
    # max |x| over one period is exactly the amplitude
    assert np.max(np.abs(ms.x[:n])) == pytest.approx(1e-4, rel=1e-12)
    # exact periodicity
    for p in range(1, 4):
        np.testing.assert_array_equal(ms.x[p * n:(p + 1) * n], ms.x[:n])
    # leakage-free spectrum: energy only on the excited bins, all equal
    X = np.fft.rfft(ms.x[:n]) * 2 / n
    mag = np.abs(X)
    off = np.ones(mag.size, bool)
    off[ms.lines_bins] = False
    assert np.max(mag[off]) < 1e-12 * np.max(mag)
    np.testing.assert_allclose(mag[ms.lines_bins], ms.line_amplitude, rtol=1e-9)
    # reported phases describe the samples
    np.testing.assert_allclose(np.angle(X[ms.lines_bins] * np.exp(-1j * ms.phases_rad)), 0, atol=1e-8)
    # starts near zero (no jump of the reference)
    assert abs(ms.x[0]) < 1e-4 * 2 * np.pi * 26 / FS * 30
    assert ms.period_s == pytest.approx(1.0)


def test_multisine_deterministic_and_seed_dependent():
    a = sg.multisine(10_000.0, 1.0, 5, 26, 1, 2, seed=7)
    b = sg.multisine(10_000.0, 1.0, 5, 26, 1, 2, seed=7)
    c = sg.multisine(10_000.0, 1.0, 5, 26, 1, 2, seed=8)
    np.testing.assert_array_equal(a.x, b.x)
    assert not np.allclose(a.x, c.x)


def test_multisine_schroeder_has_lower_crest_factor_than_worst_case():
    ms = sg.multisine(10_000.0, 1.0, 1, 100, 1, 1, seed=0, phase="schroeder")
    rms = np.sqrt(np.mean(ms.x**2))
    assert 1 / rms < 2.0  # Schroeder crest factor ~1.7 for flat spectra
    assert ms.lines_hz.size == 100


def test_multisine_non_integer_period_raises_naming_arguments():
    with pytest.raises(ValueError, match="fs_hz.*f_resolution_hz"):
        sg.multisine(83_300.0, 1e-4, 5, 26, 0.3, 2, seed=0)


def test_multisine_bad_band_raises():
    with pytest.raises(ValueError, match="f_max_hz"):
        sg.multisine(1000.0, 1.0, 30, 20, 1, 1, seed=0)
    with pytest.raises(ValueError, match="Nyquist"):
        sg.multisine(1000.0, 1.0, 30, 600, 1, 1, seed=0)
    with pytest.raises(ValueError, match="no multiple"):
        sg.multisine(1000.0, 1.0, 5.2, 5.8, 1, 1, seed=0)
    with pytest.raises(ValueError, match="periods"):
        sg.multisine(1000.0, 1.0, 5, 8, 1, 0, seed=0)


@settings(max_examples=40, deadline=None)
@given(
    n_per=st.integers(min_value=16, max_value=4000),
    res=st.sampled_from([0.5, 1.0, 2.0, 5.0]),
    k_lo=st.integers(min_value=1, max_value=20),
    n_lines=st.integers(min_value=1, max_value=30),
    periods=st.integers(min_value=1, max_value=3),
    amp=st.floats(min_value=1e-6, max_value=1e3),
    seed=st.integers(min_value=0, max_value=2**31),
)
def test_multisine_properties(n_per, res, k_lo, n_lines, periods, amp, seed):
    fs = n_per * res
    k_hi = min(k_lo + n_lines - 1, (n_per - 1) // 2)
    if k_hi < k_lo:
        return
    ms = sg.multisine(fs, amp, k_lo * res, k_hi * res, res, periods, seed)
    assert ms.samples_per_period == n_per
    np.testing.assert_array_equal(ms.lines_bins, np.arange(k_lo, k_hi + 1))
    assert np.max(np.abs(ms.x)) == pytest.approx(amp, rel=1e-12)
    one = ms.x[:n_per]
    np.testing.assert_array_equal(ms.x, np.tile(one, periods))
    mag = np.abs(np.fft.rfft(one))
    off = np.ones(mag.size, bool)
    off[ms.lines_bins] = False
    if off.any():
        assert np.max(mag[off]) <= 1e-10 * np.max(mag)
    np.testing.assert_allclose(mag[ms.lines_bins], mag[ms.lines_bins][0], rtol=1e-8)


# --------------------------------------------------------------------------------- sweep
def _zero_crossing_freqs(t, x):
    s = np.signbit(x)
    idx = np.nonzero(s[1:] != s[:-1])[0]
    # linear interpolation of each crossing instant
    tz = t[idx] - x[idx] * (t[idx + 1] - t[idx]) / (x[idx + 1] - x[idx])
    half_periods = np.diff(tz)
    return 0.5 * (tz[1:] + tz[:-1]), 1.0 / (2.0 * half_periods)


@pytest.mark.parametrize("law", ["linear", "log"])
def test_sweep_instantaneous_frequency_by_zero_crossings(law):
    fs, T = FS, 0.3
    x = sg.sweep(fs, 0.4, 99e-6, 11.0, 50.0, T, law=law)
    t = sg.time_vector(fs, 0.4)
    assert x.size == t.size == round(0.4 * fs)
    tm, f_est = _zero_crossing_freqs(t, x)
    f_true = sg.sweep_frequency_at(tm, 11.0, 50.0, T, law=law)
    # the frequency changes by at most ~1 % over a half period: compare to 1 %
    np.testing.assert_allclose(f_est, f_true, rtol=1e-2)
    after = tm > T + 0.02
    np.testing.assert_allclose(f_est[after], 50.0, rtol=1e-4)
    # constant amplitude, starts at 0, phase continuous (bounded sample-to-sample step)
    assert np.max(np.abs(x)) <= 99e-6 * (1 + 1e-12)
    assert np.max(np.abs(x)) > 0.999 * 99e-6
    assert x[0] == 0.0
    assert np.max(np.abs(np.diff(x))) <= 99e-6 * 2 * np.pi * 50.0 / fs * 1.0001


@pytest.mark.parametrize("law,method", [("linear", "linear"), ("log", "logarithmic")])
def test_sweep_matches_scipy_chirp(law, method):
    fs, T = 20_000.0, 0.5
    x = sg.sweep(fs, T, 1.0, 3.0, 80.0, T, law=law)
    t = sg.time_vector(fs, T)
    ref = scipy.signal.chirp(t, f0=3.0, t1=T, f1=80.0, method=method, phi=-90.0)
    np.testing.assert_allclose(x, ref, atol=1e-9)


def test_sweep_frequency_at_scalar_and_clipping():
    assert sg.sweep_frequency_at(0.15, 11, 50, 0.3) == pytest.approx(30.5)
    assert sg.sweep_frequency_at(-1.0, 11, 50, 0.3) == pytest.approx(11.0)
    assert sg.sweep_frequency_at(9.0, 11, 50, 0.3) == pytest.approx(50.0)
    assert sg.sweep_frequency_at(0.15, 10, 40, 0.3, law="log") == pytest.approx(20.0)
    with pytest.raises(ValueError, match="law"):
        sg.sweep_frequency_at(0.1, 1, 2, 1, law="cubic")
    with pytest.raises(ValueError, match="f_start_hz"):
        sg.sweep(1000.0, 1.0, 1.0, 0.0, 10.0, 1.0, law="log")


@settings(max_examples=30, deadline=None)
@given(
    f0=st.floats(min_value=0.5, max_value=200.0),
    f1=st.floats(min_value=0.5, max_value=200.0),
    T=st.floats(min_value=0.05, max_value=2.0),
    law=st.sampled_from(["linear", "log"]),
)
def test_sweep_phase_derivative_is_frequency(f0, f1, T, law):
    t = np.linspace(-0.1, T + 0.2, 2001)
    h = 1e-6
    dpsi = (sg.sweep_phase_rad(t + h, f0, f1, T, law) - sg.sweep_phase_rad(t - h, f0, f1, T, law)) / (2 * h)
    f = sg.sweep_frequency_at(t, f0, f1, T, law)
    # the frequency law has kinks at t = 0 and t = T: a central difference straddling one is not
    # a derivative, so those samples are left out
    smooth = (np.abs(t) > 2 * h) & (np.abs(t - T) > 2 * h)
    np.testing.assert_allclose(dpsi[smooth] / (2 * np.pi), f[smooth], rtol=1e-5, atol=1e-5)


# --------------------------------------------------------------------------------- pulses
def _runs(x):
    change = np.nonzero(np.diff(x) != 0)[0] + 1
    edges = np.concatenate([[0], change, [x.size]])
    return np.diff(edges), x[edges[:-1]]


def test_pulses_bounded_widths_deterministic():
    x = sg.pulses(FS, 0.6, 0.3, 2e-4, 4e-3, seed=1)
    assert x.dtype == np.float64 and x.size == round(0.6 * FS)
    assert set(np.unique(x)) <= {-0.3, 0.3}
    widths, levels = _runs(x)
    inner = widths[:-1] / FS  # the last pulse is cut by the end of the record
    assert inner.min() >= 2e-4 - 1e-12 and inner.max() <= 4e-3 + 1e-12
    assert np.all(levels[1:] == -levels[:-1])  # alternating signs
    np.testing.assert_array_equal(x, sg.pulses(FS, 0.6, 0.3, 2e-4, 4e-3, seed=1))
    assert not np.array_equal(x, sg.pulses(FS, 0.6, 0.3, 2e-4, 4e-3, seed=2))


def test_pulses_bad_arguments():
    with pytest.raises(ValueError, match="min_width_s"):
        sg.pulses(FS, 0.1, 1.0, 4e-3, 2e-4, seed=0)
    with pytest.raises(ValueError, match="no whole number"):
        sg.pulses(1000.0, 0.1, 1.0, 1.2e-3, 1.8e-3, seed=0)
    with pytest.raises(ValueError, match="seed"):
        sg.pulses(FS, 0.1, 1.0, 2e-4, 4e-3, seed=None)


@pytest.mark.slow
def test_pulses_spectrum_matches_documented_psd():
    fs = 10_000.0
    x = sg.pulses(fs, 200.0, 0.3, 1e-3, 2e-2, seed=4)
    f, p = scipy.signal.welch(x, fs, nperseg=8192)
    g = sg.pulses_psd(f, fs, 0.3, 1e-3, 2e-2)
    for lo, hi in [(2, 10), (10, 30), (30, 100), (100, 300), (300, 1000), (1000, 5000)]:
        m = (f >= lo) & (f < hi)
        assert p[m].mean() / g[m].mean() == pytest.approx(1.0, abs=0.06)
    # strictly positive (persistent excitation) and integrates to the power a^2
    ff = np.linspace(0, fs / 2, 200_001)
    gg = sg.pulses_psd(ff, fs, 0.3, 1e-3, 2e-2)
    assert np.all(gg > 0)
    assert np.trapezoid(gg, ff) == pytest.approx(0.09, rel=1e-3)


@settings(max_examples=40, deadline=None)
@given(
    fs=st.sampled_from([1000.0, 10_000.0, 83_300.0]),
    min_w=st.floats(min_value=1e-3, max_value=5e-3),
    extra=st.floats(min_value=0.0, max_value=1e-2),
    amp=st.floats(min_value=0.0, max_value=10.0),
    seed=st.integers(min_value=0, max_value=2**31),
)
def test_pulses_properties(fs, min_w, extra, amp, seed):
    max_w = min_w + extra + 1.0 / fs  # at least one whole number of samples fits
    x = sg.pulses(fs, 0.2, amp, min_w, max_w, seed)
    assert x.size == round(0.2 * fs)
    assert np.all(np.abs(np.abs(x) - amp) == 0)
    if amp > 0:
        widths, _ = _runs(x)
        if widths.size > 1:
            w = widths[:-1] / fs
            assert w.min() >= min_w - 1e-12 and w.max() <= max_w + 1e-12


# --------------------------------------------------------------------------------- step
def test_step():
    x = sg.step(1000.0, 0.01, 2.5, 0.004)
    np.testing.assert_array_equal(x, [0, 0, 0, 0, 2.5, 2.5, 2.5, 2.5, 2.5, 2.5])
    assert sg.step(1000.0, 0.01, 1.0, 1.0).sum() == 0


# --------------------------------------------------------------------------------- make_excitation
def test_make_excitation_config_specs():
    ms = sg.make_excitation(
        {"kind": "multisine", "point": "position", "axis": "y", "amplitude_m": 1e-4, "f_min_hz": 5.0,
         "f_max_hz": 26.0, "f_resolution_hz": 1.0, "periods": 4, "seed_offset": 4}, FS, None, seed=0)
    assert ms.kind == "multisine" and ms.unit == "m" and ms.seed == 4
    assert ms.x.size == 4 * 83_300 and ms.multisine.samples_per_period == 83_300
    direct = sg.multisine(FS, 1e-4, 5, 26, 1, 4, seed=4)
    np.testing.assert_array_equal(ms.x, direct.x)

    p = sg.make_excitation({"kind": "pulses", "amplitude_a": 0.3, "min_width_s": 2e-4,
                            "max_width_s": 4e-3, "axis": "both"}, FS, 0.6, seed=5)
    np.testing.assert_array_equal(p.x, sg.pulses(FS, 0.6, 0.3, 2e-4, 4e-3, 5))
    assert p.unit == "A" and p.t.size == p.x.size

    s = sg.make_excitation({"kind": "sweep", "amplitude_m": 99e-6, "f_start_hz": 11, "f_stop_hz": 50,
                            "sweep_duration_s": 0.3, "law": "linear"}, FS, None)
    assert s.x.size == round(0.3 * FS) and s.seed is None
    np.testing.assert_array_equal(s.x, sg.sweep(FS, 0.3, 99e-6, 11, 50, 0.3))

    z = sg.make_excitation({"kind": "none"}, FS, 0.3, seed=1)
    assert z.x.size == round(0.3 * FS) and not z.x.any()

    st_ = sg.make_excitation({"kind": "step", "amplitude_m": 1e-5, "t_step_s": 0.01}, 1000.0, 0.02)
    assert st_.x[10] == 1e-5 and st_.x[9] == 0


def test_make_excitation_scenario_multisine_defaults_and_cut():
    # rig scenario format: seed in the spec, no f_resolution_hz (defaults to 1 Hz)
    e = sg.make_excitation({"kind": "multisine", "axis": "y", "amplitude_m": 1e-4, "f_min_hz": 5,
                            "f_max_hz": 26, "periods": 4, "seed": 3}, 1000.0, 2.5)
    assert e.seed == 3 and e.x.size == 2500 and e.multisine.periods == 2.5
    np.testing.assert_array_equal(e.x, sg.multisine(1000.0, 1e-4, 5, 26, 1, 3, 3).x[:2500])


@pytest.mark.parametrize(
    "spec,match",
    [
        ({"amplitude_m": 1.0}, "kind"),
        ({"kind": "chirp"}, "kind"),
        ({"kind": "pulses", "amplitude_a": 0.3, "max_width_s": 4e-3}, "min_width_s"),
        ({"kind": "pulses", "min_width_s": 2e-4, "max_width_s": 4e-3}, "amplitude_m"),
        ({"kind": "multisine", "amplitude_m": 1e-4, "f_min_hz": 5, "f_max_hz": 26}, "periods"),
        ({"kind": "sweep", "amplitude_m": 1e-4, "f_start_hz": 5, "f_stop_hz": 26}, "sweep_duration_s"),
        ({"kind": "step", "amplitude_m": 1e-4}, "t_step_s"),
        ({"kind": "sweep", "amplitude_m": 1e-4, "f_start_hz": 5, "f_stop_hz": 26,
          "sweep_duration_s": 1, "lw": "log"}, "lw"),
        ({"kind": "step", "amplitude_m": 1e-4, "amplitude_a": 1.0, "t_step_s": 0}, "amplitude_a"),
    ],
)
def test_make_excitation_errors_name_the_key(spec, match):
    with pytest.raises(ValueError, match=match):
        sg.make_excitation(spec, 1000.0, 1.0, seed=0)


def test_make_excitation_random_kind_needs_seed_and_duration():
    with pytest.raises(ValueError, match="seed"):
        sg.make_excitation({"kind": "pulses", "amplitude_a": 0.3, "min_width_s": 2e-4,
                            "max_width_s": 4e-3}, FS, 0.1)
    with pytest.raises(ValueError, match="duration_s"):
        sg.make_excitation({"kind": "pulses", "amplitude_a": 0.3, "min_width_s": 2e-4,
                            "max_width_s": 4e-3}, FS, None, seed=1)
