"""The simulator's memoised inputs give the numbers they replace (calibration, converter noise)."""
import numpy as np

from ssamb.config import load_config
from ssamb.sim import api
from ssamb.sim.params import amb_params
from ssamb.sim.statics import network_tables


def test_a_memoised_calibration_is_the_one_computed_afresh():
    par = amb_params(load_config())
    packed, qtab = par.pack(), network_tables(par)
    api._CALIBRATIONS.clear()
    first = api.calibrate_selfsensing(par, packed, [-1e-4, 0.0, 1e-4], qtab, average_samples=100)
    first["raw_m"].append(1.0)                     # a caller's edit does not reach the memo
    again = api.calibrate_selfsensing(par, packed, [-1e-4, 0.0, 1e-4], qtab, average_samples=100)
    api._CALIBRATIONS.clear()
    fresh = api.calibrate_selfsensing(par, packed, [-1e-4, 0.0, 1e-4], qtab, average_samples=100)
    assert again == fresh and len(again["raw_m"]) == 3
    other = api.calibrate_selfsensing(par, par.pack(DEADTIME=1e-7), [-1e-4, 0.0, 1e-4], qtab, average_samples=100)
    assert other["raw_m"] != fresh["raw_m"]        # another input, another calibration


def test_cached_converter_noise_is_numpys_scaled_draws():
    par = amb_params(load_config())
    seq = np.random.SeedSequence([3, 1, 4, 1, 5])
    n = 2000
    n_per = int(n / par.fs_hz * par.f_pwm_hz) + 4
    rng = np.random.default_rng(np.random.SeedSequence([3, 1, 4, 1, 5]))
    want = rng.standard_normal((6, n))
    want[:2] *= par.position_noise_m
    want[2:] *= par.current_noise_a
    want_pi = rng.standard_normal((4, n_per)) * par.current_noise_a
    for _ in range(2):                             # drawn, then from the cache
        got, got_pi = api.converter_noise(par, n, seq)
        assert np.array_equal(got, want) and np.array_equal(got_pi, want_pi)
        got[:] = 0.0                               # the caller's copy, not the cache
