"""ssamb as an installed package: the default configuration and schema are package data, a
user's configuration is found by path or in the working directory, importing ssamb changes
nothing in the process, and a wheel installed into a fresh virtual environment simulates and
closes the loop from a folder outside the checkout."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
import yaml

from ssamb.config import DEFAULT_CONFIG_PATH, SCHEMA_PATH, find_config, load_config

ROOT = Path(__file__).resolve().parent.parent


def test_package_data_are_the_top_level_files():
    """One source: ssamb/data/*.yaml link to the files the guide places at the top level."""
    for packaged, top in (("config.yaml", "config.yaml"),
                          ("config.schema.yaml", "workflow/schemas/config.schema.yaml")):
        link = ROOT / "ssamb" / "data" / packaged
        assert link.is_symlink(), f"{link} must be a symbolic link to {top} (one source)"
        assert link.resolve() == (ROOT / top).resolve()
    assert DEFAULT_CONFIG_PATH.read_bytes() == (ROOT / "config.yaml").read_bytes()
    assert SCHEMA_PATH.read_bytes() == (ROOT / "workflow" / "schemas" / "config.schema.yaml").read_bytes()


def test_config_by_path_then_working_directory_then_package(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert find_config() == DEFAULT_CONFIG_PATH
    cfg = yaml.safe_load(DEFAULT_CONFIG_PATH.read_text())
    cfg["table1"]["i_bias_a"] = 2.75
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    assert find_config() == Path("config.yaml")
    assert load_config()["table1"]["i_bias_a"] == 2.75
    assert find_config(DEFAULT_CONFIG_PATH) == DEFAULT_CONFIG_PATH
    assert load_config(DEFAULT_CONFIG_PATH)["table1"]["i_bias_a"] != 2.75


def test_importing_ssamb_leaves_the_blas_threads_alone():
    """The library is polite: only an entry point pins BLAS (ssamb.pin_blas_threads)."""
    code = ("import numpy, scipy.linalg\nfrom threadpoolctl import threadpool_info\n"
            "n = lambda: sorted(i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas')\n"
            "before = n()\nimport ssamb, ssamb.config, ssamb.sim, ssamb.identification, ssamb.closeloop\n"
            "assert n() == before, (before, n())\nssamb.pin_blas_threads()\nprint(before, n())")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "2"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    before, after = r.stdout.split("] [")
    assert "2" in before and set(after.strip(" []\n").split(", ")) == {"1"}, r.stdout


def _wheel(src: Path, dist: Path) -> Path:
    """Build the wheel from a copy of the sources (the checkout keeps no build folder)."""
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "MANIFEST.in", "config.yaml"):
        shutil.copy(ROOT / name, src / name)
    (src / "workflow" / "schemas").mkdir(parents=True)
    shutil.copy(ROOT / "workflow" / "schemas" / "config.schema.yaml", src / "workflow" / "schemas")
    shutil.copytree(ROOT / "ssamb", src / "ssamb", symlinks=True,
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(src)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    (whl,) = dist.glob("ssamb-*.whl")
    return whl


@pytest.mark.slow
def test_wheel_in_a_fresh_environment_simulates_and_closes_the_loop(tmp_path):
    """``pip install ssamb-*.whl`` into a new virtual environment (its dependencies those of the
    test environment, linked in; ``pip check`` holds them against the wheel's requirements), then the
    command line from a folder outside the checkout, with no configuration of its own except
    the lightest close-the-loop analysis (one iteration of each fit, one candidate)."""
    whl = _wheel(tmp_path / "src", tmp_path / "dist")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    py = venv / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    Path(site, "_test_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    pip = [sys.executable, "-m", "pip", "--python", str(py)]
    r = subprocess.run(pip + ["install", "-q", "--no-deps", "--ignore-installed", str(whl)], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run(pip + ["check"], capture_output=True, text=True)      # the wheel's requirements are met
    assert r.returncode == 0, r.stdout + r.stderr

    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}

    def ssamb(*args):
        p = subprocess.run([str(py), "-m", "ssamb", *args, "--quiet"], cwd=work, env=env, capture_output=True,
                           text=True)
        assert p.returncode == 0, f"python -m ssamb {' '.join(args)}:\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}"
        return p

    where = subprocess.run([str(py), "-c", "import ssamb; print(ssamb.__file__)"], cwd=work, env=env,
                           capture_output=True, text=True, check=True).stdout
    assert where.startswith(site), where
    ssamb("simulate", "--experiment", "levitate", "--out", "lev.npz")
    assert (work / "lev.npz").stat().st_size > 10_000 and (work / "lev.json").exists()

    cfg = yaml.safe_load(DEFAULT_CONFIG_PATH.read_text())
    cfg["closeloop"].update({"replay_seeds": 2, "estimate": {"centre_runs": 2, "max_iter": 2}, "max_effects": 1,
                             "candidates_per_round": 1, "candidate_iterations": 1, "joint_iterations": 1,
                             "calibration": {"table1.i_bias_a": 0.03}, "datasets": {}})
    cfg["closeloop"].pop("default_dataset", None)
    (work / "light.yaml").write_text(yaml.safe_dump(cfg))
    (work / "rig.yaml").write_text(yaml.safe_dump({
        "experiment": {"kind": "multisine", "point": "position", "axis": "both", "amplitude_m": 3.0e-5,
                       "f_min_hz": 20, "f_max_hz": 100, "f_resolution_hz": 20, "periods": 6, "seed": 3},
        "noise": {"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": 5}}))
    ssamb("rig", "rig.yaml", "--out", "rig.npz")
    ssamb("closeloop", "rig.npz", "--out", "cl", "--config", "light.yaml", "--workers", "2")
    rep = yaml.safe_load((work / "cl" / "closeloop.json").read_text())
    assert {"effects", "unexplained", "error_before", "error_after", "parameters"} <= set(rep)
    assert sorted(p.name for p in work.iterdir()) == ["cl", "lev.json", "lev.npz", "light.yaml", "rig.json",
                                                      "rig.npz", "rig.yaml"]
