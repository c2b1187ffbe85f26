"""Closed-loop behaviour of the simulator, DCM self-sensing, config and CLI errors."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from ssamb.config import ConfigError, apply_overrides, load_config, validate_config
from ssamb.io import load_npz
from ssamb.sim import amb_params, simulate
from ssamb.sim.kernel import S_IREF, S_IREFN, S_SIZE, _control
from ssamb.sim.normal import standard_normal
from ssamb.sim.statics import equilibrium, network_tables, static_fluxes, static_forces

IDEAL_CONVERTERS = {"converters.current_noise_a": 0.0, "converters.current_adc_bits": 0,
                    "converters.position_noise_m": 0.0, "converters.position_adc_bits": 0}


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def test_open_loop_unstable_falls_on_backup_bearing(cfg):
    """Control off: negative stiffness and gravity pull the rotor onto the backup bearing."""
    n = int(0.1 * cfg["controller"]["fs_hz"])
    res = simulate(cfg, duration_s=0.1, arrays={"r_x": np.zeros(n), "r_y": np.zeros(n)},
                   pid_on=False, settle_s=0.0)
    assert res.meta["delevitation_s"] is not None
    assert res.meta["delevitation_s"] < 0.05
    clearance = cfg["table1"]["backup_clearance_m"]
    assert res.data["y_true"][-1] == pytest.approx(-clearance, abs=5e-6)


def test_levitation_from_rest_lifts_off_and_settles(cfg):
    """Controller on from rest, the DSP's converters in the loop (default noise, 12-bit
    quantisation, one sample of computation delay): lift-off, no touchdown, and the rotor settles
    near the references. Bound: the self-sensed loop jitters with the converter noise (about
    0.16 um/sqrt(Hz) of DCM estimate noise, amplified by the Table 1 loop's sensitivity peak),
    measured 5-10 um rms on y; x runs on the probe (0.2 um noise) and stays within 2 um."""
    conv = cfg["converters"]
    assert conv["current_noise_a"] > 0 and conv["current_adc_bits"] > 0 and conv["computation_delay_samples"] == 1
    res = simulate(cfg, "levitate")
    d = res.data
    clearance = cfg["table1"]["backup_clearance_m"]
    assert d["y_true"][0] < -0.99 * clearance            # starts on the backup bearing
    lifted = np.flatnonzero(d["contact"] < 0.5)
    assert lifted.size and d["t"][lifted[0]] < 0.05        # lifts off quickly
    assert res.meta["delevitation_s"] is None                # and does not touch again
    tail = d["t"] > d["t"][-1] - 0.1
    assert np.sqrt(np.mean((d["x_true"][tail] - d["r_x"][tail]) ** 2)) < 2e-6
    assert np.sqrt(np.mean((d["y_true"][tail] - d["r_y"][tail]) ** 2)) < 20e-6
    assert abs(np.mean(d["y_true"][tail] - d["r_y"][tail])) < 5e-6
    q = 2 * conv["current_adc_range_a"] / 2 ** conv["current_adc_bits"]
    assert np.allclose(d["i_ypos"] / q, np.round(d["i_ypos"] / q), atol=1e-6)   # logged = converter codes


def test_multisine_tracked_with_converter_noise(cfg):
    """The paper's 100 um multisine (5-26 Hz) with the default converters: no delevitation, and
    the rotor follows the reference as the noise-free loop does, up to the jitter the converter
    noise adds (the levitation test's 5-10 um; 15 um rms bounds it). The noise-free loop's own
    tracking error is the Table 1 loop's phase lag at up to 26 Hz."""
    ideal = simulate(apply_overrides(cfg, IDEAL_CONVERTERS), "multisine", duration_s=1.0, progress=False)
    res = simulate(cfg, "multisine", duration_s=1.0, progress=False)
    d = res.data
    assert res.meta["delevitation_s"] is None
    assert np.max(np.abs(d["r_y"])) > 50e-6
    assert np.sqrt(np.mean((d["y_true"] - ideal.data["y_true"]) ** 2)) < 15e-6
    assert np.corrcoef(d["y_true"], d["r_y"])[0, 1] > 0.95


def test_dcm_tracks_true_position_static_and_slow_move(cfg):
    """DCM estimate vs true y with ideal converters (the estimator's own error).

    Bound: the estimator is calibrated at three clamped positions; what remains is the
    lamination eddy currents' distortion of the ripple, which depends on the sampling phases of
    each window (measured about 2 um rms in the loop), and during a 5 Hz, 50 um move the lag of
    the window (84 us) plus the 800 Hz second-order low-pass (~400 us), 0.5 ms x 1.6 mm/s = 0.8
    um; 5 um bounds both.
    """
    c = apply_overrides(cfg, IDEAL_CONVERTERS)
    fs = cfg["controller"]["fs_hz"]
    n = int(0.4 * fs)
    t = np.arange(n) / fs
    static = simulate(c, duration_s=0.1, arrays={"r_y": np.zeros(int(0.1 * fs))})
    err = static.data["y_ss"] - static.data["y_true"]
    assert np.sqrt(np.mean(err**2)) < 5e-6
    ry = 50e-6 * np.sin(2 * np.pi * 5.0 * t)
    moving = simulate(c, duration_s=0.4, arrays={"r_y": ry})
    err = moving.data["y_ss"] - moving.data["y_true"]
    assert np.max(np.abs(moving.data["y_true"])) > 40e-6      # it really moved
    assert np.sqrt(np.mean(err**2)) < 5e-6


def test_peak_estimator_holds_without_eddy_currents(cfg):
    """The paper's peak DCM (max/min of the sampled ripple, volt-second compensated) levitates
    the Table 1 loop when the coil is a plain inductor; the README explains why the lamination
    eddy currents make it run away (bench/selfsensing_error.py)."""
    c = apply_overrides(cfg, {"selfsensing.estimator": "peak", "magnetics.eddy_currents": False})
    fs = cfg["controller"]["fs_hz"]
    res = simulate(c, duration_s=0.2, arrays={"r_y": np.zeros(int(0.2 * fs))})
    assert res.meta["delevitation_s"] is None
    err = res.data["y_ss"] - res.data["y_true"]
    assert np.sqrt(np.mean(err**2)) < 15e-6


def test_computation_delay_applies_command_next_sample(cfg):
    """With one sample of computation delay the amplifiers see the reference computed at the
    previous sample; without it, at once."""
    par = amb_params(cfg)
    drive = np.zeros((6, 2))
    drive[3] = (0.2, 0.5)                                # current injection on y at samples 0, 1
    rings = np.zeros((2, 256))
    for delay, expect in ((1, (3.0, 3.2)), (0, (3.2, 3.5))):
        p = par.pack(CDELAY=float(delay), PID_ON=0.0)
        st_ = np.zeros(S_SIZE)
        st_[S_IREFN:S_IREFN + 4] = 3.0
        seen = []
        for k in range(2):
            _control.py_func(st_, p, np.zeros(9), rings, k, par.fs_hz, 0.0, drive, 0.0)
            seen.append(st_[S_IREF])
        assert seen == pytest.approx(expect)


def test_weight_share_sets_the_static_load(cfg):
    """The equilibrium balances weight_share x m g; the rotor mass stays the dynamic mass."""
    for share in (1.0, 0.5, 0.0):
        c = apply_overrides(cfg, {"weight_share": share})
        par = amb_params(c)
        packed = par.pack()
        qtab = network_tables(par)
        eq = equilibrium(par, packed, qtab)
        _, fy = static_forces(packed, qtab, static_fluxes(packed, qtab, eq["currents_a"]))
        assert fy == pytest.approx(share * par.mass_kg * par.gravity_m_per_s2, abs=1e-6)
        assert par.mass_kg == cfg["table1"]["mass_kg"]
    assert abs(eq["u_y"]) < 0.05                          # no weight: (almost) no control current


def test_calibration_is_accurate(cfg):
    """Three clamped positions on a straight line: eq. (2) is linear in the airgap, so the
    residual is the converter noise averaged over 833 samples (<< 1 um) plus the slight
    curvature the eddy currents add."""
    res = simulate(cfg, duration_s=0.01, arrays={"r_y": np.zeros(833)}, settle_s=0.0)
    cal = res.meta["selfsensing_calibration"]
    assert cal["max_residual_m"] < 1e-6
    assert 0.8 < cal["gain"] < 1.2          # eq. (2) is nearly right without calibration


def test_calibration_errors_shift_and_scale_the_estimate(cfg):
    """A rig's calibration error (``selfsensing.calibration_*_error``): the loop holds the
    estimate y_ss = g e y_raw + c + dc at the reference 0, so an offset error dc moves the true
    rotor to about -dc (the calibrated part tracks y_true); a gain error e scales the estimate
    of a displaced rotor but leaves the centred rotor where it is."""
    n = int(0.06 * cfg["controller"]["fs_hz"])
    base = simulate(cfg, duration_s=0.06, arrays={"r_y": np.zeros(n)})
    off = simulate(apply_overrides(cfg, {"selfsensing.calibration_offset_error_m": 2.0e-5}), duration_s=0.06,
                   arrays={"r_y": np.zeros(n)})
    shift = np.mean(off.data["y_meas"][n // 2:]) - np.mean(base.data["y_meas"][n // 2:])
    assert shift == pytest.approx(-2.0e-5, abs=2e-6)
    assert np.mean(off.data["y_ss"][n // 2:]) == pytest.approx(0.0, abs=2e-6)
    assert off.meta["selfsensing_calibration"] == base.meta["selfsensing_calibration"]


def test_meta_is_reproducible(cfg):
    """No wall-clock time in the meta: the same inputs give the same bytes."""
    a = simulate(cfg, duration_s=0.002, arrays={"r_y": np.zeros(166)}, settle_s=0.0)
    b = simulate(cfg, duration_s=0.002, arrays={"r_y": np.zeros(166)}, settle_s=0.0)
    assert "wall_time_s" not in a.meta
    assert json.dumps(a.meta, sort_keys=True, default=str) == json.dumps(b.meta, sort_keys=True, default=str)


@pytest.mark.parametrize("seed", [0, 12345, np.random.SeedSequence([7, 5, 4, 0, 1000])])
def test_standard_normal_is_numpys(seed):
    """The compiled converter-noise draws are NumPy's, bit for bit, tail and wedge draws included
    (2 M draws: about 14 000 beyond the first ziggurat test), and leave the generator where NumPy does."""
    ref, fast = np.random.default_rng(seed), np.random.default_rng(seed)
    for shape in ((6, 250_000), (4, 90_001), 3, ()):
        a, b = ref.standard_normal(shape), standard_normal(fast, shape)
        assert a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))
    assert ref.bit_generator.state == fast.bit_generator.state
    assert ref.standard_normal() == fast.standard_normal()


def test_standard_normal_other_bit_generator_is_numpys():
    a = standard_normal(np.random.Generator(np.random.MT19937(3)), (2, 5))
    assert np.array_equal(a, np.random.Generator(np.random.MT19937(3)).standard_normal((2, 5)))


def test_same_config_same_bits(cfg):
    a = simulate(cfg, "id_validation", duration_s=0.05)
    b = simulate(cfg, "id_validation", duration_s=0.05)
    for k in ("x_meas", "y_ss", "i_ypos", "u_y"):
        assert np.array_equal(a.data[k], b.data[k])


def test_measured_format_columns(cfg, tmp_path):
    from ssamb.io import MEASURED_COLUMNS, validate_measured

    res = simulate(cfg, "id_pulses", duration_s=0.02)
    validate_measured(res.data)
    res.save(tmp_path / "x.npz")
    arrays, meta = load_npz(tmp_path / "x.npz")
    for c in MEASURED_COLUMNS:
        assert c in arrays
    assert meta["experiment"] == "id_pulses"
    assert json.loads(json.dumps(meta))["fs_hz"] == cfg["controller"]["fs_hz"]


@pytest.mark.parametrize("override, key", [
    ({"table1.mass_kg": -1.0}, "table1.mass_kg"),
    ({"table1.backup_clearance_m": 0.7e-3}, "table1.backup_clearance_m"),
    ({"controller.fs_hz": 90000.0}, "controller.fs_hz"),
    ({"magnetics.saturation": "yes"}, "magnetics.saturation"),
])
def test_bad_config_names_key(cfg, override, key):
    bad = apply_overrides(cfg, override)
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        validate_config(bad)


def test_missing_key_named(cfg):
    bad = json.loads(json.dumps(cfg))
    del bad["table1"]["coil_turns"]
    with pytest.raises(ConfigError, match=r"table1\.coil_turns.*missing"):
        validate_config(bad)


def test_unknown_override_rejected(cfg):
    with pytest.raises(ConfigError, match="does not exist"):
        apply_overrides(cfg, ["table1.mass_kgg=3"])


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "ssamb", *args], capture_output=True, text=True)


def test_cli_simulate_writes_file(tmp_path):
    out = tmp_path / "lev.npz"
    r = _cli("simulate", "--experiment", "levitate", "--set", "experiments.levitate.duration_s=0.01",
             "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    arrays, meta = load_npz(out)
    assert len(arrays["t"]) == 833 and meta["experiment"] == "levitate"
    assert out.with_suffix(".json").exists()


@pytest.mark.parametrize("args, needle", [
    (["simulate", "--experiment", "nope"], "nope"),
    (["simulate", "--experiment", "levitate", "--set", "table1.mass_kg=-2"], "table1.mass_kg"),
    (["simulate", "--experiment", "levitate", "--set", "no.such.key=1"], "does not exist"),
])
def test_cli_bad_input_one_line_no_file(tmp_path, args, needle):
    out = tmp_path / "bad.npz"
    r = _cli(*args, "--out", str(out))
    assert r.returncode == 2
    assert needle in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not out.exists() and not list(tmp_path.iterdir())


def test_cli_missing_argument():
    r = _cli("simulate", "--out", "x.npz")
    assert r.returncode == 2 and "--experiment" in r.stderr


def test_params_derivations(cfg):
    """Geometry assumptions: pole area = width x length, 100 turns per magnet."""
    par = amb_params(cfg)
    assert par.pole_area_m2 == pytest.approx(13.89e-3 * 49.15e-3)
    assert par.turns == 100
    # weight carried by a control current well below the bias
    res = simulate(cfg, duration_s=0.001, arrays={"r_y": np.zeros(83)}, settle_s=0.0)
    assert 0 < res.meta["equilibrium"]["u_y"] < 1.0


def test_axis_both_gives_independent_signals(cfg):
    """A random excitation on both axes uses independent realisations, also with a spec seed."""
    for spec_seed in (None, 5):
        exc = {"kind": "pulses", "point": "current", "axis": "both", "amplitude_a": 0.1,
               "min_width_s": 2e-4, "max_width_s": 1e-3}
        if spec_seed is not None:
            exc["seed"] = spec_seed
        res = simulate(cfg, excitation=exc, duration_s=0.02, settle_s=0.0)
        assert not np.array_equal(res.data["inj_x"], res.data["inj_y"])
        assert np.abs(res.data["inj_x"]).max() == pytest.approx(0.1)


def test_additive_quantisers_add_one_step_of_uniform_noise(cfg):
    """``converters.additive_quantisers``: the converters pass their input and the noise carries
    each rounding error, a uniform draw of one step (variance q^2/12) from its own stream: the
    Gaussian part is the rounding replay's, unchanged."""
    from ssamb.sim.api import converter_noise

    par = amb_params(cfg)
    add = amb_params(apply_overrides(cfg, {"converters.additive_quantisers": 1}))
    n, seed = 200_000, np.random.SeedSequence([3, 5])
    g, g_pi = converter_noise(par, n, seed)
    a, a_pi = converter_noise(add, n, seed)
    qx, qi = par.position_step_m, par.current_step_a
    assert qi == pytest.approx(2 * 10.0 / 2**14) and qx == pytest.approx(2 * 5e-4 / 2**12)
    for rows, q in ((slice(0, 2), qx), (slice(2, 6), qi)):
        u = (a[rows] - g[rows]) / q
        assert u.min() >= -0.5 and u.max() < 0.5
        assert np.mean(u) == pytest.approx(0.0, abs=5 * np.sqrt(1 / 12 / u.size))
        assert np.var(u) == pytest.approx(1 / 12, rel=0.01)
    assert np.all(np.abs(a_pi - g_pi) <= qi / 2)
    from ssamb.sim.params import P_I_Q, P_X_Q
    assert par.pack()[P_I_Q] == pytest.approx(qi) and add.pack()[P_I_Q] == 0.0 == add.pack()[P_X_Q]


def test_the_self_sensed_loop_is_chaotic_the_probe_loop_is_not(cfg):
    """Why replays of the AMB on common seeds are no smooth function of its parameters: a change
    of the bias current by one part in 1e10 leaves the y coil currents (the DCM self-sensed loop:
    the PWM ripple, read by the converter, sets the next duty cycles) as far from the unchanged
    replay as a replay's own jitter, 0.1 A and more; with additive quantisers the x probe's loop
    moves by less than 1e-3 of its converter noise, and with rounding by whole codes."""
    def run(over, rel):
        c = apply_overrides(cfg, {**over, "table1.i_bias_a": cfg["table1"]["i_bias_a"] * (1 + rel)})
        return simulate(c, "multisine", duration_s=0.05, progress=False).data

    rms = {}
    for label, over in (("round", {}), ("add", {"converters.additive_quantisers": 1})):
        d0, d1 = run(over, 0.0), run(over, 1e-10)
        rms[label] = {k: float(np.sqrt(np.mean((d1[k] - d0[k]) ** 2))) for k in ("x_meas", "i_ypos")}
    qx = amb_params(cfg).position_step_m
    assert rms["add"]["i_ypos"] > 0.1 and rms["round"]["i_ypos"] > 0.1
    assert rms["add"]["x_meas"] < 1e-3 * cfg["converters"]["position_noise_m"]
    assert rms["round"]["x_meas"] > 0.1 * qx


def test_stored_kernel_coefficients_are_python_controls(cfg):
    """Every stored controller of ``KERNEL_COEFFICIENTS`` is python-control's Tustin discretisation
    bit for bit (the simulator reads the table so as not to import python-control), and the
    shipped configuration's controller is in it."""
    from ssamb.sim.controller import KERNEL_COEFFICIENTS, kernel_coefficients_of_control, pid_kernel_coefficients

    for key, stored in KERNEL_COEFFICIENTS.items():
        computed = kernel_coefficients_of_control(*key)
        assert [(k, float(v).hex()) for k, v in computed] == [(k, float(v).hex()) for k, v in stored], key
    t1, ctl = cfg["table1"], cfg["controller"]
    key = (t1["pid_kp_a_per_m"], t1["pid_ki_a_per_m_s"], t1["pid_kd_a_s_per_m"], ctl["derivative_filter_hz"],
           ctl["fs_hz"])
    assert key in KERNEL_COEFFICIENTS
    assert pid_kernel_coefficients(cfg) == dict(kernel_coefficients_of_control(*key))
