"""The checks behind the bad-input table that a table row cannot show: the load
capacity is an upper bound of what the simulator carries, valid data get no plausibility note,
--force overwrites, the memory check names the experiment, YAML keys repeated deep inside."""
from __future__ import annotations

import re

import numpy as np
import pytest

from ssamb.cli import main
from ssamb.config import ConfigError, apply_overrides, load_capacity_n, load_config, read_yaml_mapping
from ssamb.errors import InputError
from ssamb.io import check_output_dir, load_measured
from ssamb.plausibility import check_measured, measured_notes

from badinputs import DEMO


@pytest.mark.parametrize("overrides", [{}, {"geometry.coils_per_magnet": 1}, {"table1.airgap_m": 1.2e-3},
                                       {"magnetics.cross_coupling": False}])
def test_load_capacity_is_an_upper_bound_of_the_simulators(overrides):
    """A weight just above the bound has no levitated equilibrium in the simulator, so the
    config check it drives never refuses a config the simulator could run."""
    from ssamb.sim.params import amb_params
    from ssamb.sim.statics import equilibrium, network_tables

    cfg = apply_overrides(load_config(), overrides)
    cap = load_capacity_n(cfg)
    heavy = apply_overrides(cfg, {"table1.mass_kg": 1.001 * cap / cfg["gravity_m_per_s2"]})
    par = amb_params(heavy)
    with pytest.raises(ConfigError, match="no levitated equilibrium"):
        equilibrium(par, par.pack(), network_tables(par))
    light = apply_overrides(cfg, {"table1.mass_kg": 0.5 * cap / cfg["gravity_m_per_s2"]})
    par = amb_params(light)
    assert abs(equilibrium(par, par.pack(), network_tables(par))["u_y"]) < cfg["controller"]["u_max_a"]


def test_valid_data_get_no_plausibility_note():
    cfg = load_config()
    arrays, meta = load_measured(DEMO)
    check_measured(arrays, cfg, "rig_demo.npz", meta)
    assert measured_notes(arrays, meta, cfg) == []


def test_simulated_current_pulses_get_no_plausibility_note():
    from ssamb.sim import simulate

    cfg = load_config()
    res = simulate(cfg, "id_pulses", duration_s=0.05, progress=False)
    arrays = {k: res.data[k] for k in ("fs_hz", "t", "r_x", "r_y", "x_meas", "y_meas", "y_ss", "i_ypos", "i_yneg",
                                       "i_xpos", "i_xneg", "u_x", "u_y", "inj_x", "inj_y")}
    check_measured(arrays, cfg, "sim", res.meta)
    assert measured_notes(arrays, res.meta, cfg) == []


def test_force_overwrites_an_output_and_its_sidecar(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text("experiment: {kind: none}\nduration_s: 0.01\n")
    out = tmp_path / "r.npz"
    out.write_text("old")
    out.with_suffix(".json").write_text("old")
    argv = ["rig", str(tmp_path / "s.yaml"), "--out", str(out), "--quiet"]
    assert main(argv) == 2 and out.read_text() == "old"
    assert "--force" in capsys.readouterr().err
    assert main(argv + ["--force"]) == 0
    assert np.load(out)["t"].size > 0 and out.with_suffix(".json").read_text() != "old"


def test_an_output_folder_with_a_previous_analysis_needs_force(tmp_path):
    def owned(p):
        return p.suffix == ".png"

    (tmp_path / "out").mkdir()
    check_output_dir(tmp_path / "out", owned)                     # empty: fine
    (tmp_path / "out" / "a.png").write_text("x")
    with pytest.raises(InputError, match="--force"):
        check_output_dir(tmp_path / "out", owned)
    check_output_dir(tmp_path / "out", owned, force=True)
    (tmp_path / "out" / "thesis.tex").write_text("x")
    with pytest.raises(InputError, match="thesis.tex"):
        check_output_dir(tmp_path / "out", owned, force=True)     # never someone else's files


def test_the_memory_check_names_the_experiment(monkeypatch):
    from ssamb.sim import api

    monkeypatch.setattr(api, "_available_memory", lambda: 10 * 2**20)
    with pytest.raises(ConfigError, match="experiment 'levitate': duration_s .* GiB"):
        api.simulate(load_config(), "levitate", progress=False)


@pytest.mark.parametrize("text, key", [
    ("a: {b: [{c: 1, c: 2}]}\n", "a.b[0].c"),
    ("a:\n  - x: 1\n  - y: 1\n    y: 2\n", "a[1].y"),
    ("base: &b {k: 1}\nuse: {<<: *b, k: 2}\n", None),       # a merge key overriding is not a repeat
])
def test_repeated_yaml_keys_are_found_where_they_are(tmp_path, text, key):
    (tmp_path / "f.yaml").write_text(text)
    if key is None:
        assert read_yaml_mapping(tmp_path / "f.yaml", "f.yaml", ConfigError)["use"]["k"] == 2
    else:
        with pytest.raises(ConfigError, match=re.escape(f"key '{key}' appears twice")):
            read_yaml_mapping(tmp_path / "f.yaml", "f.yaml", ConfigError)


def test_an_override_typed_1e30_is_a_number():
    from ssamb.config import _parse_value

    assert _parse_value("1e30") == 1e30 and _parse_value("5e-4") == 5e-4 and _parse_value("abc") == "abc"
    assert np.isnan(_parse_value("nan")) and _parse_value("[1, 2]") == [1, 2]


def test_a_shared_override_is_the_deep_copys_config_and_leaves_the_original():
    """:func:`ssamb.config.overridden` gives what :func:`ssamb.config.apply_overrides` gives, copies
    only the sections on the overridden paths (the others are the original's objects), leaves the
    original as it was and refuses a key that does not exist as the deep copy does."""
    import copy

    from ssamb.config import overridden

    cfg = load_config()
    before = copy.deepcopy(cfg)
    ov = {"table1.airgap_m": 0.61e-3, "table1.mass_kg": 4.0, "selfsensing.calibration_gain_error": 1.02,
          "closeloop.rigs.maglev1d.config": "other.yaml"}
    shared = overridden(cfg, ov)
    assert shared == apply_overrides(cfg, ov) and cfg == before
    assert shared["experiments"] is cfg["experiments"] and shared["table1"] is not cfg["table1"]
    assert shared["closeloop"]["datasets"] is cfg["closeloop"]["datasets"]
    assert shared["closeloop"]["rigs"]["maglev1d"]["fit"] is cfg["closeloop"]["rigs"]["maglev1d"]["fit"]
    assert shared["closeloop"]["rigs"]["maglev1d"] is not cfg["closeloop"]["rigs"]["maglev1d"]
    for bad in ("table1.airgap_mm", "table1.airgap_m.x", "nosection.key"):
        with pytest.raises(ConfigError) as deep:
            apply_overrides(cfg, {bad: 1.0})
        with pytest.raises(ConfigError) as light:
            overridden(cfg, {bad: 1.0})
        assert str(light.value) == str(deep.value)
