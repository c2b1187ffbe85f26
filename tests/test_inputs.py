"""Bad input through the command line: one line naming the file and the key or column, exit
status 2, no output file (issue 14). Plus the writers' file modes, the directory swap and the
line between input errors (one line) and programming errors (traceback).

Every case fails while the input is read, before any simulation, so the table is fast: it calls
:func:`ssamb.cli.main` in-process (one subprocess test checks ``python -m ssamb`` itself).
"""
from __future__ import annotations

import copy
import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from ssamb.cli import main
from ssamb.config import SCHEMA_PATH, ConfigError
from ssamb.errors import InputError, nonfinite_keys
from ssamb.io import MEASURED_COLUMNS, DataError, atomic_path, replace_dir, write_json
from ssamb.rig import ScenarioError
from ssamb.sim.effects import EFFECTS, EffectError

REPO = Path(__file__).resolve().parent.parent
FS = 83300.0
N = 400


# ------------------------------------------------------------------------------------------
# helpers
def _fails(capsys, argv, out: Path, *names: str) -> str:
    """Run the CLI; assert exit 2, exactly one stderr line containing every name, no output."""
    before = set(out.parent.iterdir()) if out.parent.exists() else set()
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, err
    assert len(lines) == 1, err
    for name in names:
        assert name in lines[0], f"{name!r} not in {lines[0]!r}"
    assert not out.exists() or out in before, f"{out} was written"
    after = set(out.parent.iterdir()) if out.parent.exists() else set()
    assert after <= before | {out.parent}, f"left behind: {sorted(p.name for p in after - before)}"
    return lines[0]


def _arrays() -> dict:
    t = np.arange(N) / FS
    a = {c: np.zeros(N) for c in MEASURED_COLUMNS}
    a["t"] = t
    a["r_y"] = 1e-5 * np.sin(2 * np.pi * 50 * t)
    a["fs_hz"] = np.asarray(FS)
    return a


META = {"kind": "rig", "excitation": {"kind": "multisine", "point": "position", "axis": "y", "seed": 3},
        "start": "levitated"}


def _npz(path: Path, arrays: dict, meta=META) -> Path:
    payload = dict(arrays)
    if meta is not None:
        payload["meta"] = np.asarray(meta if isinstance(meta, str) else json.dumps(meta))
    with open(path, "wb") as fh:
        np.savez(fh, **payload)
    return path


def _csv(path: Path, arrays: dict, sidecar=None, cols=None) -> Path:
    cols = cols if cols is not None else list(MEASURED_COLUMNS)
    rows = [",".join(cols)] + [",".join(repr(float(arrays[c][i])) for c in cols) for i in range(N)]
    path.write_text("\n".join(rows) + "\n")
    side = {"fs_hz": FS, "meta": META} if sidecar is None else sidecar
    path.with_suffix(".json").write_text(side if isinstance(side, str) else json.dumps(side))
    return path


def _closeloop(capsys, data: Path, tmp_path: Path, *names: str) -> str:
    out = tmp_path / "out"
    return _fails(capsys, ["closeloop", data, "--out", out, "--quiet"], out, data.name, *names)


# ------------------------------------------------------------------------------------------
# measured data (closeloop)
def test_valid_data_passes_the_loader(tmp_path):
    from ssamb.io import load_measured

    for f in (_npz(tmp_path / "d.npz", _arrays()), _csv(tmp_path / "d.csv", _arrays())):
        arrays, meta = load_measured(f)
        assert meta == META and np.array_equal(arrays["r_y"], _arrays()["r_y"])


@pytest.mark.parametrize("column", ("fs_hz",) + MEASURED_COLUMNS)
def test_npz_without_a_required_column(capsys, tmp_path, column):
    a = _arrays()
    del a[column]
    _closeloop(capsys, _npz(tmp_path / "d.npz", a), tmp_path, f"missing required column(s): {column}")


@pytest.mark.parametrize("column", MEASURED_COLUMNS)
def test_csv_without_a_required_column(capsys, tmp_path, column):
    f = _csv(tmp_path / "d.csv", _arrays(), cols=[c for c in MEASURED_COLUMNS if c != column])
    _closeloop(capsys, f, tmp_path, column)


def test_csv_sidecar_without_fs_hz(capsys, tmp_path):
    f = _csv(tmp_path / "d.csv", _arrays(), sidecar={"meta": META})
    _fails(capsys, ["closeloop", f, "--out", tmp_path / "out"], tmp_path / "out", "d.json", "'fs_hz'")


def _cut(path: Path, keep: float) -> Path:
    b = path.read_bytes()
    path.write_bytes(b[: int(len(b) * keep)])
    return path


def _damage_member(path: Path) -> Path:
    b = bytearray(path.read_bytes())
    i = b.index(b"\x93NUMPY", b.index(b"x_meas.npy")) + 200   # inside the x_meas data
    b[i:i + 8] = b"\xff" * 8
    path.write_bytes(bytes(b))
    return path


NPZ_CASES = {
    "empty file": lambda p: (p.write_bytes(b""), p)[1],
    "cut short": lambda p: _cut(_npz(p, _arrays()), 0.6),
    "damaged member": lambda p: _damage_member(_npz(p, _arrays())),
    "not a zip": lambda p: (p.write_text("t,x\n1,2\n"), p)[1],
    "meta not JSON": lambda p: _npz(p, _arrays(), meta="{kind: rig"),
    "meta a list": lambda p: _npz(p, _arrays(), meta="[1, 2]"),
}


@pytest.mark.parametrize("case", NPZ_CASES)
def test_unreadable_npz(capsys, tmp_path, case):
    line = _closeloop(capsys, NPZ_CASES[case](tmp_path / "d.npz"), tmp_path)
    assert "Traceback" not in line


def _with(**cols):
    a = _arrays()
    a.update(cols)
    return a


COLUMN_CASES = {
    "NaN in a column": (_with(x_meas=np.r_[np.zeros(N - 1), np.nan]), "'x_meas'"),
    "inf in a column": (_with(i_xneg=np.r_[np.inf, np.zeros(N - 1)]), "'i_xneg'"),
    "text column": (_with(u_x=np.array(["a"] * N)), "'u_x'"),
    "complex column": (_with(u_y=np.zeros(N, complex)), "'u_y'"),
    "short column": (_with(y_ss=np.zeros(N - 3)), "'y_ss'"),
    "2-D column": (_with(r_x=np.zeros((N, 2))), "'r_x'"),
    "fs_hz NaN": (_with(fs_hz=np.asarray(np.nan)), "'fs_hz'"),
    "fs_hz text": (_with(fs_hz=np.asarray("abc")), "'fs_hz'"),
    "fs_hz disagrees with t": (_with(fs_hz=np.asarray(1000.0)), "'fs_hz'"),
}


@pytest.mark.parametrize("case", COLUMN_CASES)
def test_bad_npz_column(capsys, tmp_path, case):
    arrays, name = COLUMN_CASES[case]
    _closeloop(capsys, _npz(tmp_path / "d.npz", arrays), tmp_path, name)


META_CASES = {
    "NaN in meta": ({**META, "settle_s": float("nan")}, "settle_s"),
    "seed is text": ({**META, "excitation": {**META["excitation"], "seed": "abc"}}, "excitation.seed"),
    "excitation a list": ({**META, "excitation": [1]}, "excitation"),
    "unknown start": ({**META, "start": "hovering"}, "start"),
}


@pytest.mark.parametrize("case", META_CASES)
def test_bad_meta(capsys, tmp_path, case):
    meta, key = META_CASES[case]
    _closeloop(capsys, _npz(tmp_path / "d.npz", _arrays(), meta=meta), tmp_path, f"meta key '{key}")


def _csv_text(p: Path, text: str, sidecar=None) -> Path:
    p.write_text(text)
    p.with_suffix(".json").write_text(json.dumps({"fs_hz": FS, "meta": META}) if sidecar is None else sidecar)
    return p


def _csv_cell(value: str, row: int = 5, col: str = "y_ss") -> str:
    """CSV text with data row ``row`` (file line ``row + 1``) cell ``col`` replaced."""
    a = _arrays()
    cols = list(MEASURED_COLUMNS)
    lines = [",".join(cols)] + [",".join(repr(float(a[c][i])) for c in cols) for i in range(N)]
    cells = lines[row].split(",")
    cells[cols.index(col)] = value
    lines[row] = ",".join(cells)
    return "\n".join(lines) + "\n"


CSV_CASES = {
    "empty csv": ("", None, ("empty",)),
    "header only": (",".join(MEASURED_COLUMNS) + "\n", None, ("no data rows",)),
    "text cell": (_csv_cell("abc"), None, ("'y_ss'", "line 6", "'abc'")),
    "empty cell": (_csv_cell(""), None, ("'y_ss'", "line 6")),
    "NaN cell": (_csv_cell("nan"), None, ("'y_ss'", "non-finite")),
    "short row": (_csv_cell("1,2"), None, ("line 6",)),
    "repeated column": (",".join(MEASURED_COLUMNS + ("t",)) + "\n", None, ("'t'",)),
    "binary": ("\udcff", None, ("UTF-8",)),
}


@pytest.mark.parametrize("case", CSV_CASES)
def test_bad_csv(capsys, tmp_path, case):
    text, side, names = CSV_CASES[case]
    p = tmp_path / "d.csv"
    if case == "binary":
        p.write_bytes(b"\xff\xfe\x00garbage")
        p.with_suffix(".json").write_text(json.dumps({"fs_hz": FS, "meta": META}))
    else:
        _csv_text(p, text, side)
    _closeloop(capsys, p, tmp_path, *names)


SIDECAR_CASES = {
    "malformed JSON": ('{"fs_hz": 83300, ', ("not valid JSON",)),
    "not an object": ("[83300]", ("object",)),
    "fs_hz text": (json.dumps({"fs_hz": "abc", "meta": META}), ("'fs_hz'",)),
    "fs_hz NaN": ('{"fs_hz": NaN, "meta": {}}', ("'fs_hz'", "finite")),
    "fs_hz boolean": (json.dumps({"fs_hz": True, "meta": META}), ("'fs_hz'",)),
    "NaN in meta": ('{"fs_hz": 83300.0, "meta": {"excitation": {"amplitude_m": Infinity}}}',
                    ("meta.excitation.amplitude_m", "finite")),
    "meta string not JSON": (json.dumps({"fs_hz": FS, "meta": "{kind"}), ("'meta'",)),
}


@pytest.mark.parametrize("case", SIDECAR_CASES)
def test_bad_csv_sidecar(capsys, tmp_path, case):
    side, names = SIDECAR_CASES[case]
    f = _csv(tmp_path / "d.csv", _arrays(), sidecar=side)
    out = tmp_path / "out"
    _fails(capsys, ["closeloop", f, "--out", out], out, "d.json", *names)


def test_missing_data_file_and_unknown_format(capsys, tmp_path):
    _closeloop(capsys, tmp_path / "nothing.npz", tmp_path, "not found")
    (tmp_path / "d.mat").write_text("x")
    _closeloop(capsys, tmp_path / "d.mat", tmp_path, "unknown data format")


def test_closeloop_never_replaces_a_folder_with_foreign_files(capsys, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    rc = main(["closeloop", str(_npz(tmp_path / "d.npz", _arrays())), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "notes.txt" in err and str(out) in err
    assert (out / "notes.txt").read_text() == "mine" and len(list(out.iterdir())) == 1


def test_closeloop_config_with_nan(capsys, tmp_path):
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    cfg["closeloop"]["alpha_accept"] = float("nan")
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp_path / "out"
    _fails(capsys, ["closeloop", _npz(tmp_path / "d.npz", _arrays()), "--out", out, "--config", tmp_path / "c.yaml"],
           out, "c.yaml", "closeloop.alpha_accept")


# ------------------------------------------------------------------------------------------
# config (simulate)
def _simulate(capsys, tmp_path, *extra, config=None, names=()):
    out = tmp_path / "sim.npz"
    argv = ["simulate", "--experiment", "levitate", "--out", out, "--quiet", *extra]
    if config is not None:
        argv += ["--config", config]
    return _fails(capsys, argv, out, *names)


@pytest.mark.parametrize("key", [
    "simulation.contact_damping_n_s_per_m", "table1.pid_kp_a_per_m", "table1.pid_kd_a_s_per_m",
    "table1.mass_kg", "table1.r_coil_ohm", "table1.coil_turns", "selfsensing.calibration_positions_m",
])
@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_nonfinite_override(capsys, tmp_path, key, value):
    _simulate(capsys, tmp_path, "--set", f"{key}={value}", names=("config.yaml", key.split(".")[0], "finite"))


def test_nonfinite_value_in_config_file(capsys, tmp_path):
    text = (REPO / "config.yaml").read_text()
    assert "mass_kg: 3.86" in text
    (tmp_path / "c.yaml").write_text(text.replace("mass_kg: 3.86", "mass_kg: .nan"))
    _simulate(capsys, tmp_path, config=tmp_path / "c.yaml", names=("c.yaml", "table1.mass_kg", "finite"))


@pytest.mark.parametrize("setting, key", [
    ("experiments.levitate.excitation.amplitude_m=.nan", "experiments.levitate.excitation.amplitude_m"),
    ("experiments.id_pulses.excitation.amplitude_a=abc", "experiments.id_pulses.excitation"),
    ("experiments.multisine.excitation.periods=[1, 2]", "experiments.multisine.excitation"),
    ("table1.mass_kg=abc", "table1.mass_kg"),
    ("table1.mass_kg", "table1.mass_kg"),
    ("table1.no_such_key=1", "table1.no_such_key"),
])
def test_bad_override(capsys, tmp_path, setting, key):
    _simulate(capsys, tmp_path, "--set", setting, names=(key,))


def _resolve(schema: dict, node: dict) -> dict:
    while "$ref" in node:
        node = schema["$defs"][node["$ref"].split("/")[-1]]
    return node


def _required_paths(schema: dict, node: dict, cfg, prefix: tuple = ()):
    """Dotted paths of every key the schema requires that the config has (a walk of both)."""
    node = _resolve(schema, node)
    if not isinstance(cfg, dict):
        return
    props = node.get("properties", {})
    for k in node.get("required", []):
        if k in cfg:
            yield prefix + (k,)
    for k, v in cfg.items():
        sub = props.get(k, node.get("additionalProperties") if k not in props else None)
        if isinstance(sub, dict):
            yield from _required_paths(schema, sub, v, prefix + (k,))


SCHEMA = yaml.safe_load(SCHEMA_PATH.read_text())
CONFIG = yaml.safe_load((REPO / "config.yaml").read_text())
CONFIG_REQUIRED = [".".join(p) for p in _required_paths(SCHEMA, SCHEMA, CONFIG)]


def test_the_required_key_table_covers_the_schema():
    assert len(CONFIG_REQUIRED) > 80
    assert {"seed", "table1.mass_kg", "experiments.levitate.excitation.kind", "mu.n_points"} <= set(CONFIG_REQUIRED)


@pytest.mark.parametrize("key", CONFIG_REQUIRED)
def test_config_without_a_required_key(capsys, tmp_path, key):
    cfg = copy.deepcopy(CONFIG)
    *parents, last = key.split(".")
    node = cfg
    for p in parents:
        node = node[p]
    del node[last]
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    _simulate(capsys, tmp_path, config=tmp_path / "c.yaml", names=("c.yaml", f"'{key}'"))


def test_bad_cli_arguments(capsys, tmp_path):
    _fails(capsys, ["simulate", "--experiment", "nope", "--out", tmp_path / "a.npz"], tmp_path / "a.npz", "nope")
    _fails(capsys, ["simulate", "--experiment", "levitate", "--out", tmp_path / "a.txt"], tmp_path / "a.txt", ".npz")
    _fails(capsys, ["simulate", "--experiment", "levitate", "--config", tmp_path / "none.yaml", "--out",
                    tmp_path / "a.npz"], tmp_path / "a.npz", "none.yaml", "not found")
    (tmp_path / "bad.yaml").write_text("table1: [1, 2\n")
    _fails(capsys, ["simulate", "--experiment", "levitate", "--config", tmp_path / "bad.yaml", "--out",
                    tmp_path / "a.npz"], tmp_path / "a.npz", "bad.yaml", "YAML")


# ------------------------------------------------------------------------------------------
# scenario (rig)
def _effect_example(name: str) -> dict:
    values = {"axis": "both", "delay_s": 2e-5, "speed_hz": 30.0, "mass_ecc_kgm": 1e-5, "fx_n": 1.0,
              "fy_n": 0.0, "gain": 1.02, "deadtime_s": 1e-7, "coefficient": 0.01}
    return {"name": name, **{k: values[k] for k in EFFECTS[name][0]}}


SCENARIO = {
    "config": str(REPO / "config.yaml"),
    "experiment": {"kind": "pulses", "point": "current", "axis": "both", "amplitude_a": 0.1,
                   "min_width_s": 2e-4, "max_width_s": 4e-3, "seed": 3},
    "duration_s": 0.05,
    "effects": [_effect_example(n) for n in EFFECTS if EFFECTS[n][0]],
    "noise": {"position_m": 3e-8, "current_a": 3e-4, "seed": 11},
}


def _scenario_required():
    yield ("experiment",), "experiment"
    for k in ("kind", "amplitude_a", "min_width_s", "max_width_s"):
        yield ("experiment", k), k
    yield ("duration_s",), "duration_s"
    yield ("noise", "seed"), "noise.seed"
    for i, e in enumerate(SCENARIO["effects"]):
        yield ("effects", i, "name"), f"effects[{i}]"
        for k in EFFECTS[e["name"]][0]:
            yield ("effects", i, k), k


SCENARIO_REQUIRED = list(_scenario_required())


def _rig(capsys, tmp_path, sc, *names):
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(sc))
    out = tmp_path / "rig.npz"
    return _fails(capsys, ["rig", tmp_path / "s.yaml", "--out", out, "--quiet"], out, "s.yaml", *names)


@pytest.mark.parametrize("path, name", SCENARIO_REQUIRED, ids=[".".join(map(str, p)) for p, _ in SCENARIO_REQUIRED])
def test_scenario_without_a_required_key(capsys, tmp_path, path, name):
    sc = copy.deepcopy(SCENARIO)
    node = sc
    for p in path[:-1]:
        node = node[p]
    del node[path[-1]]
    _rig(capsys, tmp_path, sc, name)


def _set(path, value):
    sc = copy.deepcopy(SCENARIO)
    node = sc
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return sc


_CC = next(i for i, e in enumerate(SCENARIO["effects"]) if e["name"] == "cross_coupling")
SCENARIO_CASES = {
    "coefficient NaN": (_set(("effects", _CC, "coefficient"), float("nan")), (f"effects[{_CC}].coefficient", "finite")),
    "coefficient a list": (_set(("effects", _CC, "coefficient"), [1, 2]), (f"effects[{_CC}]", "coefficient")),
    "coefficient text": (_set(("effects", _CC, "coefficient"), "abc"), (f"effects[{_CC}]", "coefficient", "'abc'")),
    "delay text": (_set(("effects", 0, "delay_s"), "abc"), ("effects[0]", "delay_s")),
    "axis a number": (_set(("effects", 0, "axis"), 3), ("effects[0]", "axis")),
    "unknown effect": (_set(("effects", 0, "name"), "gremlins"), ("effects[0]", "gremlins")),
    "noise NaN": (_set(("noise", "position_m"), float("nan")), ("noise.position_m",)),
    "amplitude inf": (_set(("experiment", "amplitude_a"), float("inf")), ("experiment.amplitude_a",)),
    "amplitude text": (_set(("experiment", "amplitude_a"), "abc"), ("experiment", "amplitude_a")),
    "duration NaN": (_set(("duration_s",), float("nan")), ("duration_s",)),
    "unknown key": (_set(("colour",), "red"), ("colour",)),
    "config with NaN": (None, ("key 'config'", "table1.mass_kg")),
}


@pytest.mark.parametrize("case", SCENARIO_CASES)
def test_bad_scenario(capsys, tmp_path, case):
    sc, names = SCENARIO_CASES[case]
    if sc is None:
        text = (REPO / "config.yaml").read_text().replace("mass_kg: 3.86", "mass_kg: .nan")
        (tmp_path / "c.yaml").write_text(text)
        sc = _set(("config",), str(tmp_path / "c.yaml"))
    _rig(capsys, tmp_path, sc, *names)


def test_scenario_file_problems(capsys, tmp_path):
    out = tmp_path / "rig.npz"
    _fails(capsys, ["rig", tmp_path / "none.yaml", "--out", out], out, "none.yaml", "not found")
    (tmp_path / "s.yaml").write_text("experiment: [1, 2\n")
    _fails(capsys, ["rig", tmp_path / "s.yaml", "--out", out], out, "s.yaml", "YAML")
    (tmp_path / "s.yaml").write_text("- 1\n")
    _fails(capsys, ["rig", tmp_path / "s.yaml", "--out", out], out, "s.yaml", "mapping")


# ------------------------------------------------------------------------------------------
# the error classes, the walk, programming errors
def test_every_input_error_is_an_input_error_and_a_value_error():
    for cls in (ConfigError, DataError, ScenarioError, EffectError):
        assert issubclass(cls, InputError) and issubclass(cls, ValueError)


def test_nonfinite_walk_names_nested_keys():
    obj = {"a": {"b": [1.0, float("nan")], "c": True}, "d": float("-inf"), "e": "nan", "f": None, "g": 2**70}
    assert dict(nonfinite_keys(obj)).keys() == {"a.b[1]", "d"}


@pytest.mark.parametrize("exc", [KeyError("experiments"), TypeError("bug"), IndexError("bug")])
def test_programming_errors_keep_their_traceback(monkeypatch, exc):
    import ssamb.cli as cli

    def boom(args):
        raise exc

    monkeypatch.setattr(cli, "_cmd_simulate", boom)
    with pytest.raises(type(exc)):
        cli.main(["simulate", "--experiment", "levitate", "--out", "x.npz"])


def test_python_m_ssamb_prints_one_line_and_exits_2(tmp_path):
    out = tmp_path / "s.npz"
    r = subprocess.run([sys.executable, "-m", "ssamb", "simulate", "--experiment", "levitate", "--set",
                        "table1.mass_kg=.nan", "--out", str(out)], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and "table1.mass_kg" in r.stderr and "config.yaml" in r.stderr
    assert not out.exists()


# ------------------------------------------------------------------------------------------
# writers: permissions follow the umask; a directory output is replaced whole
@pytest.mark.parametrize("umask", [0o022, 0o027, 0o077])
def test_atomic_writer_honours_the_umask(tmp_path, umask):
    old = os.umask(umask)
    try:
        write_json(tmp_path / "a.json", {"x": 1})
        with atomic_path(tmp_path / "b.html") as tmp:
            tmp.write_text("<p>")
        with open(tmp_path / "plain.txt", "w") as fh:
            fh.write("x")
    finally:
        os.umask(old)
    mode = stat.S_IMODE((tmp_path / "plain.txt").stat().st_mode)
    assert mode == 0o666 & ~umask
    for name in ("a.json", "b.html"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == mode, name


def _owned(p: Path) -> bool:
    return p.is_file() and p.suffix == ".png"


def test_replace_dir_leaves_exactly_the_new_files(tmp_path):
    target = tmp_path / "out"
    target.mkdir()
    (target / "sensor_ratio.png").write_text("old")
    (target / "evidence.png").write_text("old")
    new = tmp_path / ".new"
    new.mkdir()
    (new / "evidence.png").write_text("new")
    old = os.umask(0o022)
    try:
        replace_dir(new, target, _owned)
    finally:
        os.umask(old)
    assert sorted(p.name for p in target.iterdir()) == ["evidence.png"]
    assert (target / "evidence.png").read_text() == "new"
    assert stat.S_IMODE(target.stat().st_mode) == 0o755
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]      # nothing left aside


def test_replace_dir_refuses_foreign_files(tmp_path):
    target = tmp_path / "out"
    target.mkdir()
    (target / "thesis.tex").write_text("keep")
    new = tmp_path / ".new"
    new.mkdir()
    with pytest.raises(InputError, match="thesis.tex"):
        replace_dir(new, target, _owned)
    assert (target / "thesis.tex").read_text() == "keep"
