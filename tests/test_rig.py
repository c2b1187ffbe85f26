"""Tests of the simulated rig (``python -m ssamb rig``): format, noise model, validation."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from ssamb.acquisition import ANALOG_CHANNELS, apply_acquisition
from ssamb.cli import main
from ssamb.config import apply_overrides, config_hash, load_config
from ssamb.io import MEASURED_COLUMNS, load_measured
from ssamb.rig import ScenarioError, load_scenario, rig_data, run_scenario

REPO = Path(__file__).resolve().parent.parent
EXC = {"kind": "multisine", "point": "position", "axis": "both", "amplitude_m": 2.0e-5, "f_min_hz": 10,
       "f_max_hz": 50, "f_resolution_hz": 10, "periods": 2, "seed": 3}


def _scenario(tmp_path: Path, name: str = "s.yaml", **kw) -> Path:
    shutil.copy(REPO / "config.yaml", tmp_path / "config.yaml")
    sc = {"config": "config.yaml", "experiment": dict(EXC),
          "effects": [{"name": "static_load", "fx_n": 2.0, "fy_n": 0.0}],
          "noise": {"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": 11}}
    sc.update(kw)
    sc = {k: v for k, v in sc.items() if v is not None}
    p = tmp_path / name
    p.write_text(yaml.safe_dump(sc))
    return p


@pytest.fixture(scope="module")
def rig_pair(tmp_path_factory):
    """The same scenario with two noise seeds (and the files)."""
    tmp = tmp_path_factory.mktemp("rig")
    out = []
    for seed in (11, 12):
        sc = _scenario(tmp, f"s{seed}.yaml", noise={"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": seed})
        f = tmp / f"d{seed}.npz"
        run_scenario(sc, f, progress=False)
        out.append(f)
    return out


def test_rig_writes_only_the_measured_data_format(rig_pair):
    arrays, meta = load_measured(rig_pair[0])
    assert set(arrays) == set(MEASURED_COLUMNS) | {"fs_hz", "inj_x", "inj_y"}
    text = json.dumps(meta)
    for word in ("static_load", "effects", "fx_n", "noise", "current_a"):
        assert word not in text, f"meta names the hidden {word}"
    exc = meta["excitation"]
    assert exc["kind"] == "multisine" and exc["axis"] == "both" and exc["point"] == "position"
    assert exc["seed"] == 3 and exc["axis_seeds"] == {"x": 3, "y": 3 + 7919}
    assert exc["samples_per_period"] == 8330 and exc["lines_hz"] == [10.0, 20.0, 30.0, 40.0, 50.0]
    # axis: both excites x and y with independent realisations
    assert not np.allclose(arrays["r_x"], arrays["r_y"])
    side = json.loads(Path(rig_pair[0]).with_suffix(".json").read_text())
    assert side == meta
    assert "acquisition" not in meta          # no logging chain declared: no filter, no key


def test_logging_noise_is_outside_the_loop(rig_pair):
    (a, _), (b, _) = (load_measured(f) for f in rig_pair)
    # controller outputs are digital: noise-free, and the loop (its converters seeded from the
    # excitation seed) is the same whatever the logging noise, so they are identical
    for c in ("u_x", "u_y", "r_x", "r_y", "t"):
        np.testing.assert_array_equal(a[c], b[c])
    for c, s in (("x_meas", 3e-8), ("y_meas", 3e-8), ("y_ss", 3e-8), ("i_ypos", 3e-4), ("i_xneg", 3e-4)):
        d = (a[c] - b[c]) / np.sqrt(2)
        assert abs(np.std(d) / s - 1) < 0.05, c
    # the static load is there (integral action: it shows in the x currents, not the position)
    assert np.mean(a["u_x"]) < -0.02


@pytest.mark.parametrize("mutate, key", [
    ({"effects": [{"name": "magic_field", "strength": 1}]}, "magic_field"),
    ({"effects": [{"name": "sensor_delay", "axis": "x"}]}, "delay_s"),
    ({"effects": [{"name": "sensor_gain", "axis": "z", "gain": 1.1}]}, "axis"),
    ({"noise": {"position_m": -1e-8, "current_a": 1e-4, "seed": 1}}, "noise.position_m"),
    ({"noise": {"position_m": 1e-8, "current_a": 1e-4}}, "noise.seed"),
    ({"noise": {"position_m": 1e-8, "current_a": 1e-4, "seed": 1, "colour": "pink"}}, "noise.colour"),
    ({"experiment": None}, "experiment"),
    ({"experiment": {"kind": "multisine", "axis": "y", "amplitude_m": 1e-5}}, "f_min_hz"),
    ({"config": "nowhere.yaml"}, "config"),
    ({"duration": 1.0}, "duration"),
    ({"output": {"dtype": "int8"}}, "output.dtype"),
    ({"overrides": {"table1.mas_kg": 4.0}}, "overrides.table1.mas_kg"),
    ({"overrides": {"table1.mass_kg": float("nan")}}, "overrides.table1.mass_kg"),
    ({"overrides": {"converters.current_noise_a": float("inf")}}, "overrides.converters.current_noise_a"),
    ({"overrides": {"table1.mass_kg": -4.0}}, "overrides.table1.mass_kg"),
    ({"overrides": {"converters.current_adc_bits": 12.5}}, "overrides.converters.current_adc_bits"),
    ({"overrides": {"table1.airgap_m": 1.0e-4}}, "overrides.table1.airgap_m"),   # a cross-key rule
    ({"overrides": {"converters": {"current_adc_bits": 12}}}, "overrides.converters"),
    ({"overrides": ["table1.mass_kg=4.0"]}, "overrides"),
    ({"acquisition": {"antialias_hz": 5.0e4, "order": 4}}, "acquisition.antialias_hz"),
    ({"acquisition": {"antialias_hz": 1.0e4, "order": 9}}, "acquisition.order"),
    ({"acquisition": {"antialias_hz": 1.0e4, "kind": "bessel"}}, "acquisition.kind"),
])
def test_bad_scenarios_name_the_key_and_write_nothing(tmp_path, mutate, key):
    sc = _scenario(tmp_path, **mutate)
    out = tmp_path / "out.npz"
    with pytest.raises(ScenarioError, match=re.escape(f"{sc}: ") + ".*" + re.escape(key)) as exc:
        run_scenario(sc, out, progress=False)
    assert "\n" not in str(exc.value)
    if key.split(".")[0] in ("overrides", "acquisition"):
        assert str(exc.value).startswith(f"{sc}: key '{key}': ")
    assert not out.exists() and not out.with_suffix(".json").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.yaml", "s.yaml"]


def test_cli_rig_bad_input_one_line_exit_2(tmp_path, capsys):
    sc = _scenario(tmp_path, effects=[{"name": "magic_field"}])
    assert main(["rig", str(sc), "--out", str(tmp_path / "o.npz"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "magic_field" in err[0]


def test_scenario_paths_relative_to_the_scenario(tmp_path):
    sub = tmp_path / "deep"
    sub.mkdir()
    (sub / "f.csv").write_text("t,fx_n,fy_n\n0,0,0\n1,1,0\n")
    sc = _scenario(sub, effects=[{"name": "external_force", "file": "f.csv"}])
    s = load_scenario(sc)
    assert Path(s["effects"][0]["file"]) == (sub / "f.csv").resolve()
    assert s["seed"] == 3 and "seed" not in s["excitation"]
    sc = _scenario(sub, name="t.yaml", effects=[{"name": "external_force", "file": "missing.csv"}])
    with pytest.raises(ScenarioError, match="missing.csv"):
        load_scenario(sc)


# ---- the rig's own parameters (overrides) -------------------------------------------------

REST = {"experiment": {"kind": "none"}, "duration_s": 0.02, "effects": None}


@pytest.fixture(scope="module")
def heavier_rig(tmp_path_factory):
    """A nominal rig and one whose rotor is 5 % heavier (an override), with the equilibrium the
    simulator computed for each (a spy on ``simulate``), and the heavier rig's written meta."""
    import ssamb.sim

    tmp = tmp_path_factory.mktemp("heavier")
    m0 = load_config()["table1"]["mass_kg"]
    seen = []
    real = ssamb.sim.simulate

    def spy(cfg, *args, **kwargs):
        res = real(cfg, *args, **kwargs)
        seen.append(res.meta["equilibrium"]["u_y"])
        return res

    mp = pytest.MonkeyPatch()
    mp.setattr(ssamb.sim, "simulate", spy)
    try:
        run_scenario(_scenario(tmp, "nominal.yaml", **REST), tmp / "nominal.npz", progress=False)
        ov = {"table1.mass_kg": 1.05 * m0, "magnetics.iron_conductivity_s_per_m": 1.8e6,
              "converters.current_adc_bits": 13}
        run_scenario(_scenario(tmp, "heavy.yaml", overrides=ov, **REST), tmp / "heavy.npz", progress=False)
    finally:
        mp.undo()
    return {"u_eq": seen, "overrides": ov, "meta": load_measured(tmp / "heavy.npz")[1],
            "nominal_hash": config_hash(load_config(tmp / "config.yaml"))}


def test_an_override_reaches_the_rigs_physics(heavier_rig):
    """The weight is carried by the control current: at the centre the force is k_i u_y
    (linear in u_y: (i_0 + u)^2 - (i_0 - u)^2 = 4 i_0 u), so u_y at equilibrium scales with the
    mass: 5 % heavier, 5 % more current."""
    u_nominal, u_heavy = heavier_rig["u_eq"]
    assert u_nominal > 0.3
    assert abs(u_heavy / u_nominal - 1.05) < 1e-4


def test_meta_never_reveals_the_overrides(heavier_rig):
    meta, ov = heavier_rig["meta"], heavier_rig["overrides"]
    text = json.dumps(meta)
    for key, value in ov.items():
        for word in (key, key.split(".")[-1], repr(value), f"{value:.6g}", f"{value:.4g}"):
            assert word not in text, f"meta reveals the override {key}: {word}"
    assert "overrides" not in text
    assert meta["config_hash"] == heavier_rig["nominal_hash"]     # the nominal config's, not the rig's


@pytest.mark.slow
def test_a_heavier_rig_logs_5_percent_more_static_current(tmp_path):
    """The same as :func:`test_an_override_reaches_the_rigs_physics` on the logged data: the
    mean of u_y over 1 s at rest (the integral action holds the weight; the 0.24 A rms jitter
    of the loop leaves the 1 s mean within about 0.002 A)."""
    m0 = load_config()["table1"]["mass_kg"]
    mean_u = []
    for name, ov in (("a.yaml", None), ("b.yaml", {"table1.mass_kg": 1.05 * m0})):
        sc = _scenario(tmp_path, name, experiment={"kind": "none"}, duration_s=1.0, effects=None, overrides=ov)
        arrays, _ = rig_data(load_scenario(sc))
        mean_u.append(float(np.mean(arrays["u_y"])))
    assert abs(mean_u[1] / mean_u[0] - 1.05) < 0.015, mean_u


def test_a_section_override_replaces_the_section_as_apply_overrides_does(tmp_path):
    cfg = load_config()
    section = {**cfg["converters"], "current_adc_bits": 12}
    s = load_scenario(_scenario(tmp_path, overrides={"converters": section}))
    assert s["cfg"] == apply_overrides(cfg, {"converters.current_adc_bits": 12})
    assert s["nominal_config_hash"] == config_hash(cfg)


def test_cli_rig_bad_override_one_line_exit_2(tmp_path, capsys):
    sc = _scenario(tmp_path, overrides={"table1.mas_kg": 4.0})
    out = tmp_path / "o.npz"
    assert main(["rig", str(sc), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{sc}: key 'overrides.table1.mas_kg': " in err[0]
    assert not out.exists() and not out.with_suffix(".json").exists()


# ---- the logging chain (acquisition) ------------------------------------------------------

ACQ = {"antialias_hz": 2000.0, "order": 4}
LOG_NOISE = {"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": 11}


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """One rig (0.2 s multisine) logged three ways: raw, through the filter, and through the
    filter with logging noise."""
    tmp = tmp_path_factory.mktemp("chain")
    kinds = {"raw": {"noise": None}, "filtered": {"noise": None, "acquisition": ACQ},
             "logged": {"noise": LOG_NOISE, "acquisition": ACQ}}
    return {k: rig_data(load_scenario(_scenario(tmp, f"{k}.yaml", **kw))) for k, kw in kinds.items()}


def test_the_filter_acts_on_the_logged_analog_channels_only(chain):
    from scipy.signal import welch

    (raw, raw_meta), (filt, filt_meta) = chain["raw"], chain["filtered"]
    fs = float(raw["fs_hz"])
    expected = apply_acquisition(raw, ACQ, fs)
    for c in ANALOG_CHANNELS:
        np.testing.assert_array_equal(filt[c], expected[c])
        f, p_raw = welch(raw[c], fs=fs, nperseg=1024)
        _, p_filt = welch(filt[c], fs=fs, nperseg=1024)
        high = f > 3 * ACQ["antialias_hz"]                 # |H| < 3^-4 there: power down > 6000x
        assert np.sum(p_filt[high]) < 1e-3 * np.sum(p_raw[high]), c
    for c in ("y_ss", "u_x", "u_y", "r_x", "r_y", "inj_x", "inj_y", "t"):
        np.testing.assert_array_equal(filt[c], raw[c])     # the DSP's digital values, and the loop itself
    assert filt_meta["acquisition"] == ACQ and "acquisition" not in raw_meta


def test_logging_noise_is_added_after_the_filter(chain):
    """The logged minus the filtered record is the logging noise: white, at its level, above
    the cutoff as below it (noise added before the filter would fall off as (f_c/f)^8)."""
    from scipy.signal import welch

    (filt, _), (logged, _) = chain["filtered"], chain["logged"]
    fs = float(filt["fs_hz"])
    for c, sigma in (("x_meas", LOG_NOISE["position_m"]), ("i_ypos", LOG_NOISE["current_a"])):
        f, p = welch(logged[c] - filt[c], fs=fs, nperseg=1024)
        white = 2 * sigma ** 2 / fs                            # one-sided PSD of white noise
        below = np.mean(p[(f > 0) & (f < ACQ["antialias_hz"] / 2)])
        above = np.mean(p[(f > 3 * ACQ["antialias_hz"]) & (f < 0.9 * fs / 2)])
        assert abs(below / white - 1) < 0.25 and abs(above / white - 1) < 0.1, (c, below / white, above / white)
