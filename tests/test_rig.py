"""Tests of the simulated rig (``python -m ssamb rig``): format, noise model, validation."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from ssamb.cli import main
from ssamb.io import MEASURED_COLUMNS, load_measured
from ssamb.rig import ScenarioError, load_scenario, run_scenario

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


def test_logging_noise_is_outside_the_loop(rig_pair):
    (a, _), (b, _) = (load_measured(f) for f in rig_pair)
    # controller outputs are digital: noise-free, and the loop runs noise-free, so they are
    # identical whatever the logging noise
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
])
def test_bad_scenarios_name_the_key_and_write_nothing(tmp_path, mutate, key):
    sc = _scenario(tmp_path, **mutate)
    out = tmp_path / "out.npz"
    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        run_scenario(sc, out, progress=False)
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
