"""The bad-input table: what a careless user feeds ssamb, and what must happen.

Every row is a bad input to one entry point: a config file (``--config``), a ``--set`` override,
a rig scenario, an NPZ or CSV data file, the command line and its output locations, data that
are valid but suspicious (the plausibility notes), and the workflow. Each row says what must
happen:

* ``cli`` rows: ``python -m ssamb ...`` exits with status 2 and prints exactly one line that
  names every listed word (the file and the key or column), no traceback, and the case's folder
  holds the same files with the same contents afterwards (nothing written, nothing overwritten);
* ``note`` rows: close the loop's plausibility notes (:func:`ssamb.plausibility.measured_notes`)
  on data that pass every error check include a note naming the listed words;
* ``workflow`` rows: ``snakemake`` stops with the status the README states (2 for a bad config,
  at parse time, one line; 1 for a failed job, whose log holds the reason), no traceback, and no
  result written.

:func:`run_case` runs one row and classifies the outcome: ``ok``, ``traceback``, ``accepted``
(exit 0, or no note: a silent acceptance), ``wrong status``, ``not one line``, ``unnamed`` (the
line misses a listed word), ``wrote files``, or ``skipped`` (a row that needs what this machine
lacks, e.g. a non-root user). ``tests/test_bad_inputs.py`` asserts ``ok`` for every row;
``bench/bad_inputs.py`` re-runs the whole table and prints the counts.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import io
import json
import logging
import os
import shutil
import subprocess
import sys
import traceback
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

REPO = Path(__file__).resolve().parent.parent
DEMO = REPO / "resources" / "rig_demo.npz"
CONFIG_TEXT = (REPO / "config.yaml").read_text()


@dataclass(frozen=True)
class Case:
    """One row: ``make(folder)`` builds the input files in ``folder`` and returns the command
    line (``ssamb`` arguments for ``cli``, ``snakemake`` arguments for ``workflow``, or
    ``(arrays, meta, cfg)`` for ``note``); ``names`` must appear in the message (or the note)."""

    id: str
    area: str
    make: Callable
    names: tuple = ()
    kind: str = "cli"
    status: int = 2
    log: str | None = None  # workflow: the job log that must hold the message


@dataclass(frozen=True)
class Outcome:
    case: Case
    verdict: str
    detail: str


# ------------------------------------------------------------------------------------------
# building blocks
def _config() -> dict:
    return yaml.safe_load(CONFIG_TEXT)


def _set(cfg: dict, dotted: str, value) -> dict:
    *parents, last = dotted.split(".")
    node = cfg
    for p in parents:
        node = node[p]
    if value is _DELETE:
        del node[last]
    else:
        node[last] = value
    return cfg


_DELETE = object()


def config_file(d: Path, name: str = "c.yaml", text: str | None = None, **edits) -> Path:
    """A config file in ``d``: the repository's with dotted ``edits`` (``a__b`` for ``a.b``), or ``text``."""
    path = d / name
    if text is None:
        cfg = _config()
        for k, v in edits.items():
            _set(cfg, k.replace("__", "."), v)
        text = yaml.safe_dump(cfg, sort_keys=False)
    path.write_text(text)
    return path


def replace_once(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def simulate(d: Path, *extra, config: Path | None = None) -> list:
    argv = ["simulate", "--experiment", "levitate", "--out", d / "sim.npz", "--quiet", *extra]
    return argv + (["--config", config] if config is not None else [])


def scenario(d: Path, sc: dict | None = None, text: str | None = None, name: str = "s.yaml", **edits) -> list:
    """``rig`` on a scenario in ``d``: a valid short one with ``edits`` (``None`` deletes a key)."""
    if text is None:
        sc = copy.deepcopy(sc if sc is not None else BASE_SCENARIO)
        for k, v in edits.items():
            if v is None:
                sc.pop(k, None)
            else:
                sc[k] = v
        text = yaml.safe_dump(sc, sort_keys=False)
    (d / name).write_text(text)
    return ["rig", d / name, "--out", d / "rig.npz", "--quiet"]


BASE_SCENARIO = {"config": str(REPO / "config.yaml"), "experiment": {"kind": "none"}, "duration_s": 0.02}


def force_csv(d: Path, text: str) -> list:
    (d / "force.csv").write_text(text)
    return scenario(d, effects=[{"name": "external_force", "file": "force.csv"}])


def effect(d: Path, **e) -> list:
    return scenario(d, effects=[e])


#: samples of the demo data the rows use: its first four multisine periods (0.8 s), enough for
#: close the loop to split it (so that a row accepted by mistake would run an analysis)
DEMO_SAMPLES = 4 * 16660


@functools.lru_cache(maxsize=1)
def _demo() -> tuple[dict, dict]:
    from ssamb.io import load_measured

    arrays, meta = load_measured(DEMO)
    return {k: np.asarray(v, float)[:DEMO_SAMPLES] if np.ndim(v) else v for k, v in arrays.items()}, meta


def demo(**changes) -> tuple[dict, dict]:
    """The demo rig's data (valid, excited) with columns replaced (``None`` deletes one)."""
    arrays, meta = _demo()
    arrays = dict(arrays)
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = v
    return arrays, copy.deepcopy(meta)


def npz(d: Path, arrays: dict | None = None, meta=None, name: str = "d.npz", raw_meta: str | None = None) -> Path:
    """An NPZ data file in ``d`` (``meta`` embedded as JSON, or ``raw_meta`` as is)."""
    if arrays is None:
        arrays, m = demo()
        meta = m if meta is None else meta
    payload = dict(arrays)
    payload["meta"] = np.asarray(raw_meta if raw_meta is not None else json.dumps(meta))
    with open(d / name, "wb") as fh:
        np.savez(fh, **payload)
    return d / name


def closeloop(d: Path, data: Path, *extra) -> list:
    return ["closeloop", data, "--out", d / "out", "--quiet", "--workers", "1", *extra]


def npz_case(d: Path, meta=None, **changes) -> list:
    arrays, m = demo(**changes)
    return closeloop(d, npz(d, arrays, m if meta is None else meta))


def scaled(names, factor, **more) -> dict:
    arrays, _ = _demo()
    out = {c: arrays[c] * factor for c in names}
    out.update(more)
    return out


POSITIONS = ("x_meas", "y_meas", "y_ss")
CURRENTS = ("i_ypos", "i_yneg", "i_xpos", "i_xneg")
CSV_COLUMNS = ("t", "r_x", "r_y", "x_meas", "y_meas", "y_ss", "i_ypos", "i_yneg", "i_xpos", "i_xneg", "u_x", "u_y")


def csv(
    d: Path,
    cell: tuple | None = None,
    sidecar=None,
    columns=CSV_COLUMNS,
    rows: int = 30000,
    text: str | None = None,
    arrays: dict | None = None,
    sep: str = ",",
) -> list:
    """``closeloop`` on a CSV of the demo data's first ``rows`` samples with its sidecar; ``cell``
    = (row, column, text) replaces one cell."""
    path = d / "d.csv"
    if text is None:
        a, meta = demo()
        a = arrays or a
        lines = [sep.join(columns)]
        for i in range(rows):
            lines.append(sep.join(repr(float(a[c][i])) for c in columns))
        if cell is not None:
            row, col, value = cell
            cells = lines[row].split(sep)
            cells[columns.index(col)] = value
            lines[row] = sep.join(cells)
        text = "\n".join(lines) + "\n"
    path.write_text(text)
    if sidecar is not False:
        side = {"fs_hz": 83300.0, "meta": _demo()[1]} if sidecar is None else sidecar
        (d / "d.json").write_text(side if isinstance(side, str) else json.dumps(side))
    return closeloop(d, path)


@functools.lru_cache(maxsize=1)
def _csv_text() -> str:
    a, _ = _demo()
    lines = [",".join(CSV_COLUMNS)] + [",".join(repr(float(a[c][i])) for c in CSV_COLUMNS) for i in range(30000)]
    return "\n".join(lines) + "\n"


def readonly(folder: Path) -> Path:
    """Make ``folder`` unwritable: mode 0o555, and as root (whom modes do not stop) the
    immutable attribute (``chattr +i``); :func:`release` undoes both."""
    folder.mkdir(parents=True, exist_ok=True)
    os.chmod(folder, 0o555)
    if os.geteuid() == 0:
        r = subprocess.run(["chattr", "+i", str(folder)], capture_output=True) if shutil.which("chattr") else None
        if r is None or r.returncode != 0:
            raise _Skip("a read-only folder needs chattr as root")
    return folder


def release(folder: Path) -> None:
    """Undo :func:`readonly` under ``folder`` so that it can be deleted."""
    if os.geteuid() == 0 and shutil.which("chattr"):
        subprocess.run(["chattr", "-R", "-i", str(folder)], capture_output=True)
    for p in [folder, *folder.rglob("*")]:
        if p.is_dir() and not p.is_symlink():
            try:
                os.chmod(p, 0o755)
            except OSError:
                pass


class _Skip(Exception):
    """The case needs what this machine lacks."""


def unreadable(path: Path) -> Path:
    """``path`` (a small config unless it exists) without read permission."""
    if not path.exists():
        path.write_text("table1: {}\n")
    os.chmod(path, 0)
    if os.geteuid() == 0:
        raise _Skip("an unreadable file needs a non-root user")
    return path


def io_error_file(path: Path) -> Path:
    """A file whose read fails with an I/O error (a link to ``/proc/self/mem``)."""
    if not Path("/proc/self/mem").exists():
        raise _Skip("needs /proc/self/mem")
    path.symlink_to("/proc/self/mem")
    return path


def binary(path: Path) -> Path:
    """A file of bytes that are not UTF-8 text."""
    path.write_bytes(b"\xff\xfe\x00\x81\xa3" * 20)
    return path


def npy(path: Path) -> Path:
    """A single NumPy array (``.npy`` content) under ``path``."""
    with open(path, "wb") as fh:
        np.save(fh, np.zeros(3))
    return path


def existing(path: Path, text: str = "mine") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------------------
# the rows
def _cfg_cases() -> list[Case]:
    """``--config FILE``: the file itself, its keys, its values (units off by 1000 included)."""
    rows = []

    def c(id, names, make, area="config"):
        rows.append(Case(id, area, make, tuple(names)))

    def edit(id, names, **edits):
        c(id, ("c.yaml",) + tuple(names), lambda d: simulate(d, config=config_file(d, **edits)))

    def text(id, names, fn):
        c(id, ("c.yaml",) + tuple(names), lambda d: simulate(d, config=config_file(d, text=fn(CONFIG_TEXT))))

    c("config is a folder", ("cfg", "folder"), lambda d: simulate(d, config=(d / "cfg").mkdir() or d / "cfg"))
    c("config is binary", ("bin.yaml", "UTF-8"), lambda d: simulate(d, config=binary(d / "bin.yaml")))
    c(
        "config unreadable (permission)",
        ("u.yaml", "cannot be read"),
        lambda d: simulate(d, config=unreadable(d / "u.yaml")),
    )
    c(
        "config read fails (I/O error)",
        ("io.yaml", "cannot be read"),
        lambda d: simulate(d, config=io_error_file(d / "io.yaml")),
    )
    c("config not found", ("none.yaml", "not found"), lambda d: simulate(d, config=d / "none.yaml"))
    text("config empty", ("mapping",), lambda t: "")
    text("config a list", ("mapping",), lambda t: "- 1\n- 2\n")
    text("config invalid YAML", ("YAML",), lambda t: "table1: [1, 2\n")
    text("config tab indentation", ("YAML",), lambda t: replace_once(t, "  mass_kg:", "\tmass_kg:"))
    text(
        "duplicate key in a section",
        ("table1.mass_kg", "twice"),
        lambda t: replace_once(t, "  mass_kg: 3.86", "  mass_kg: 3.86\n  mass_kg: 3.96"),
    )
    text("duplicate section", ("seed", "twice"), lambda t: t + "\nseed: 7\n")
    text(
        "duplicate key in a flow mapping",
        ("experiments.levitate.excitation.kind", "twice"),
        lambda t: replace_once(t, "excitation: {kind: none}", "excitation: {kind: none, kind: step}"),
    )
    text(
        "number written 1e30",
        ("table1.mass_kg", "1e30", "text"),
        lambda t: replace_once(t, "mass_kg: 3.86", "mass_kg: 1e30"),
    )
    text("NaN in the file", ("table1.mass_kg", "finite"), lambda t: replace_once(t, "mass_kg: 3.86", "mass_kg: .nan"))
    text(
        "infinity in the file",
        ("controller.fs_hz", "finite"),
        lambda t: replace_once(t, "fs_hz: 83300.0", "fs_hz: .inf"),
    )
    edit("unknown section", ("colour", "unknown"), colour="red")
    edit("misspelt key", ("table1", "mass_kgs"), table1__mass_kgs=3.86)
    edit("missing section", ("controller", "missing"), controller=_DELETE)
    edit("missing key", ("table1.airgap_m", "missing"), table1__airgap_m=_DELETE)
    edit("text for a number", ("table1.mass_kg",), table1__mass_kg="heavy")
    edit("list for a number", ("table1.mass_kg",), table1__mass_kg=[1, 2])
    edit("null for a number", ("table1.mass_kg",), table1__mass_kg=None)
    edit("boolean for a number", ("table1.mass_kg",), table1__mass_kg=True)
    edit("negative mass", ("table1.mass_kg",), table1__mass_kg=-3.86)
    units = [
        ("airgap in mm", "table1.airgap_m", 0.6),
        ("airgap in um as mm", "table1.airgap_m", 6e-7),
        ("clearance in um", "table1.backup_clearance_m", 250.0),
        ("mass 1e30", "table1.mass_kg", 1e30),
        ("bias in mA", "table1.i_bias_a", 3000.0),
        ("supply in mV", "table1.v_supply_v", 50000.0),
        ("switching frequency in kHz", "table1.f_pwm_hz", 30.0),
        ("turns 5e6", "table1.coil_turns", 5e6),
        ("axial length in mm", "table1.axial_length_m", 49.15),
        ("pole width in mm", "table1.pole_width_m", 13.89),
        ("stator radius in mm", "table1.r_stator_outer_m", 75.0),
        ("controller rate in kHz", "controller.fs_hz", 83.3),
        ("output clamp in mA", "controller.u_max_a", 3000.0),
        ("current clamp in mA", "amplifier.i_ref_max_a", 10000.0),
        ("gravity in mm/s^2", "gravity_m_per_s2", 9810.0),
        ("knee in mT", "magnetics.b_knee_t", 1300.0),
        ("lamination in mm", "magnetics.lamination_thickness_m", 0.35),
        ("conductivity beyond copper's", "magnetics.iron_conductivity_s_per_m", 2e12),
        ("probe bandwidth in MHz", "sensors.x_bandwidth_hz", 0.02),
        ("pre-roll in ms", "simulation.settle_s", 50.0),
        ("ADC range in um", "converters.position_adc_range_m", 500.0),
    ]
    for id, key, value in units:
        edit(id, (key, "plausible"), **{key.replace(".", "__"): value})
    edit("mass in g (beyond the load capacity)", ("table1.mass_kg", "weight"), table1__mass_kg=3860.0)
    edit("coil resistance in mohm", ("table1.r_coil_ohm", "table1.v_supply_v"), table1__r_coil_ohm=200.0)
    edit("PID gain in A/mm", ("table1.pid_kp_a_per_m",), table1__pid_kp_a_per_m=20.0)
    edit(
        "calibration positions in um",
        ("selfsensing.calibration_positions_m",),
        selfsensing__calibration_positions_m=[-100.0, 0.0, 100.0],
    )
    edit(
        "excitation amplitude in um",
        ("experiments.sweep.excitation.amplitude_m", "airgap"),
        experiments__sweep__excitation__amplitude_m=99.0,
    )
    edit(
        "injection amplitude in mA",
        ("experiments.id_pulses.excitation.amplitude_a",),
        experiments__id_pulses__excitation__amplitude_a=300.0,
    )
    edit("duration 1e9 s", ("experiments.levitate.duration_s", "samples"), experiments__levitate__duration_s=1e9)
    edit(
        "multisine periods 1e8",
        ("experiments.multisine", "periods", "samples"),
        experiments__multisine__excitation__periods=100000000,
    )
    edit(
        "multisine resolution 1e-7 Hz",
        ("experiments.multisine", "f_resolution_hz", "samples"),
        experiments__multisine__excitation__f_resolution_hz=1e-7,
    )
    edit("sweep record 1e9 s", ("experiments.sweep.duration_s", "samples"), experiments__sweep__duration_s=1e9)
    edit("clearance not below the airgap", ("table1.backup_clearance_m", "airgap"), table1__backup_clearance_m=7e-4)
    edit("rate a multiple of the PWM", ("controller.fs_hz", "multiple"), controller__fs_hz=90000.0)
    edit(
        "derivative filter above Nyquist",
        ("controller.derivative_filter_hz", "Nyquist"),
        controller__derivative_filter_hz=50000.0,
    )
    edit("low-pass above Nyquist", ("selfsensing.lowpass_hz", "Nyquist"), selfsensing__lowpass_hz=50000.0)
    edit("duty limits crossed", ("amplifier.duty_min",), amplifier__duty_min=0.9, amplifier__duty_max=0.1)
    edit("radii out of order", ("table1.r_pole_m", "larger"), table1__r_pole_m=0.02)
    edit("weight share 2", ("weight_share",), weight_share=2.0)
    edit("six poles", ("geometry.n_poles",), geometry__n_poles=6)
    edit("unknown eddy model", ("magnetics.eddy_model",), magnetics__eddy_model="foo")
    edit(
        "unknown excitation kind",
        ("experiments.levitate.excitation", "noise"),
        experiments__levitate__excitation={"kind": "noise"},
    )
    edit(
        "unknown excitation key",
        ("experiments.sweep.excitation", "amplitude_mm"),
        experiments__sweep__excitation__amplitude_mm=1.0,
    )
    edit("unknown start", ("experiments.levitate.start",), experiments__levitate__start="hover")
    edit("no experiments", ("experiments",), experiments={})
    edit("model order above the horizon", ("identification.plant.order", "ss_f"), identification__plant__order=40)
    edit(
        "uncertainty on a pulse experiment",
        ("uncertainty.experiment", "multisine"),
        uncertainty__experiment="id_pulses",
    )
    edit("mu band reversed", ("mu.f_min_hz",), mu__f_min_hz=5000.0)
    edit("mu grid 1e9 points", ("mu.n_points",), mu__n_points=1000000000)
    edit("unknown experiment referenced", ("identification.estimation", "nope"), identification__estimation="nope")
    edit(
        "study key not in the config",
        ("study.assumptions", "key"),
        study__assumptions={"x": {"key": "table1.no_such", "values": [1.0]}},
    )
    return rows


def _set_cases() -> list[Case]:
    """``--set KEY=VALUE`` on ``simulate``."""
    rows = []
    for id, setting, names in [
        ("no '='", "table1.mass_kg", ("table1.mass_kg", "KEY=VALUE")),
        ("empty key", "=3", ("''",)),
        ("unknown key", "table1.no_such_key=1", ("table1.no_such_key", "does not exist")),
        ("unknown section", "nope.mass_kg=1", ("nope", "does not exist")),
        ("text for a number", "table1.mass_kg=abc", ("table1.mass_kg",)),
        ("list for a number", "table1.mass_kg=[1, 2]", ("table1.mass_kg",)),
        ("NaN", "table1.mass_kg=.nan", ("table1.mass_kg", "finite")),
        ("nan", "table1.mass_kg=nan", ("table1.mass_kg", "finite")),
        ("infinity", "controller.fs_hz=.inf", ("controller.fs_hz", "finite")),
        ("minus infinity", "table1.airgap_m=-.inf", ("table1.airgap_m", "finite")),
        ("airgap in mm", "table1.airgap_m=0.6", ("table1.airgap_m", "plausible")),
        ("mass 1e30 (no dot)", "table1.mass_kg=1e30", ("table1.mass_kg", "plausible")),
        ("mass in g", "table1.mass_kg=3860", ("table1.mass_kg", "weight")),
        ("negative mass", "table1.mass_kg=-1", ("table1.mass_kg",)),
        ("bias in mA", "table1.i_bias_a=3000", ("table1.i_bias_a", "plausible")),
        ("duration 1e9 s", "experiments.levitate.duration_s=1e9", ("experiments.levitate.duration_s", "samples")),
        ("multisine periods 1e8", "experiments.multisine.excitation.periods=100000000", ("periods", "samples")),
        ("zero substeps", "simulation.substeps=0", ("simulation.substeps",)),
        ("a million substeps", "simulation.substeps=1000000", ("simulation.substeps",)),
        ("negative seed", "seed=-1", ("seed",)),
        ("fractional seed", "seed=1.5", ("seed",)),
        ("unknown start", "experiments.levitate.start=hover", ("experiments.levitate.start",)),
        ("unknown excitation kind", "experiments.levitate.excitation.kind=noise", ("experiments.levitate.excitation",)),
        ("a section replaced by a number", "table1=3", ("table1",)),
        ("a section emptied", "table1={}", ("table1",)),
        ("no experiments", "experiments={}", ("experiments",)),
        ("rate a multiple of the PWM", "controller.fs_hz=90000.0", ("controller.fs_hz", "multiple")),
        ("clearance not below the airgap", "table1.backup_clearance_m=0.001", ("table1.backup_clearance_m",)),
        (
            "calibration beyond the clearance",
            "selfsensing.calibration_positions_m=[0.001, 0.0]",
            ("selfsensing.calibration_positions_m",),
        ),
        ("six poles", "geometry.n_poles=6", ("geometry.n_poles",)),
        ("64-bit ADC", "converters.current_adc_bits=64", ("converters.current_adc_bits",)),
        (
            "amplitude in um",
            "experiments.sweep.excitation.amplitude_m=99",
            ("experiments.sweep.excitation.amplitude_m",),
        ),
    ]:
        rows.append(
            Case(
                f"--set {id}",
                "set",
                functools.partial(lambda d, s: simulate(d, "--set", s), s=setting),
                ("config.yaml",) + names,
            )
        )
    return rows


def _scenario_cases() -> list[Case]:
    """``rig SCENARIO.yaml``: the file, its keys, its effects, an external force's file."""
    rows = []

    def c(id, names, make):
        rows.append(Case(f"scenario {id}", "scenario", make, tuple(names)))

    s = ("s.yaml",)
    c("not found", ("none.yaml", "not found"), lambda d: ["rig", d / "none.yaml", "--out", d / "rig.npz"])
    c("a folder", ("sf", "folder"), lambda d: ["rig", (d / "sf").mkdir() or d / "sf", "--out", d / "rig.npz"])
    c("binary", s + ("UTF-8",), lambda d: ["rig", binary(d / "s.yaml"), "--out", d / "rig.npz"])
    c("empty", s + ("mapping",), lambda d: scenario(d, text=""))
    c("invalid YAML", s + ("YAML",), lambda d: scenario(d, text="experiment: [1, 2\n"))
    c("a list", s + ("mapping",), lambda d: scenario(d, text="- 1\n"))
    c(
        "duplicate key",
        s + ("duration_s", "twice"),
        lambda d: scenario(d, text=yaml.safe_dump(BASE_SCENARIO) + "duration_s: 0.5\n"),
    )
    c("no experiment", s + ("experiment", "missing"), lambda d: scenario(d, experiment=None))
    c("unknown key", s + ("colour",), lambda d: scenario(d, colour="red"))
    c("experiment a number", s + ("experiment",), lambda d: scenario(d, experiment=3))
    c("unknown experiment name", s + ("nope",), lambda d: scenario(d, experiment="nope"))
    c("experiment without kind", s + ("experiment.kind",), lambda d: scenario(d, experiment={"axis": "y"}))
    c("unknown excitation kind", s + ("experiment", "noise"), lambda d: scenario(d, experiment={"kind": "noise"}))
    c(
        "unknown excitation key",
        s + ("experiment", "amplitude_mm"),
        lambda d: scenario(d, experiment={"kind": "step", "amplitude_mm": 1, "t_step_s": 0.01}),
    )
    c("negative seed", s + ("experiment.seed",), lambda d: scenario(d, experiment={"kind": "none", "seed": -3}))
    c("no duration", s + ("duration_s", "missing"), lambda d: scenario(d, duration_s=None))
    c("duration NaN", s + ("duration_s", "finite"), lambda d: scenario(d, duration_s=float("nan")))
    c("duration negative", s + ("duration_s",), lambda d: scenario(d, duration_s=-1.0))
    c("duration 1e9 s", s + ("duration_s", "samples"), lambda d: scenario(d, duration_s=1e9))
    c("duration as text", s + ("duration_s",), lambda d: scenario(d, duration_s="short"))
    c("unknown start", s + ("start",), lambda d: scenario(d, start="hover"))
    c("config not found", s + ("config", "nothing.yaml"), lambda d: scenario(d, config=str(d / "nothing.yaml")))
    c("config a folder", s + ("config", "folder"), lambda d: scenario(d, config=str((d / "cf").mkdir() or d / "cf")))
    c(
        "config with NaN",
        s + ("config", "table1.mass_kg", "finite"),
        lambda d: scenario(
            d, config=str(config_file(d, text=replace_once(CONFIG_TEXT, "mass_kg: 3.86", "mass_kg: .nan")))
        ),
    )
    c(
        "config with duplicate key",
        s + ("config", "table1.mass_kg", "twice"),
        lambda d: scenario(
            d,
            config=str(
                config_file(d, text=replace_once(CONFIG_TEXT, "  mass_kg: 3.86", "  mass_kg: 3.86\n  mass_kg: 3.9"))
            ),
        ),
    )
    c("overrides a list", s + ("overrides",), lambda d: scenario(d, overrides=[1]))
    c(
        "override of no key",
        s + ("overrides.table1.mass_kgs",),
        lambda d: scenario(d, overrides={"table1.mass_kgs": 4.0}),
    )
    c(
        "override airgap in mm",
        s + ("overrides.table1.airgap_m", "plausible"),
        lambda d: scenario(d, overrides={"table1.airgap_m": 0.6}),
    )
    c(
        "override mass in g",
        s + ("overrides.table1.mass_kg", "weight"),
        lambda d: scenario(d, overrides={"table1.mass_kg": 3860.0}),
    )
    c(
        "override NaN",
        s + ("table1.mass_kg", "finite"),
        lambda d: scenario(d, overrides={"table1.mass_kg": float("nan")}),
    )
    c("override text", s + ("overrides.table1.mass_kg",), lambda d: scenario(d, overrides={"table1.mass_kg": "heavy"}))
    c("noise not a mapping", s + ("noise",), lambda d: scenario(d, noise=3))
    c("noise unknown key", s + ("noise.colour",), lambda d: scenario(d, noise={"colour": 1, "seed": 1}))
    c("noise negative", s + ("noise.position_m",), lambda d: scenario(d, noise={"position_m": -1e-8, "seed": 1}))
    c("noise without seed", s + ("noise.seed",), lambda d: scenario(d, noise={"position_m": 1e-8}))
    c("noise seed text", s + ("noise.seed",), lambda d: scenario(d, noise={"position_m": 1e-8, "seed": "x"}))
    c("anti-alias above Nyquist", s + ("acquisition",), lambda d: scenario(d, acquisition={"antialias_hz": 1e6}))
    c("acquisition unknown key", s + ("acquisition",), lambda d: scenario(d, acquisition={"colour": 1}))
    c("output dtype int8", s + ("output.dtype",), lambda d: scenario(d, output={"dtype": "int8"}))
    c("output unknown key", s + ("output",), lambda d: scenario(d, output={"compress": True}))
    c("effects not a list", s + ("effects",), lambda d: scenario(d, effects={"name": "static_load"}))
    c("effect not a mapping", s + ("effects[0]",), lambda d: scenario(d, effects=["static_load"]))
    c("effect without name", s + ("effects[0]", "name"), lambda d: effect(d, fx_n=1.0, fy_n=0.0))
    c("unknown effect", s + ("effects[0]", "gremlins"), lambda d: effect(d, name="gremlins"))
    c("effect missing parameter", s + ("effects[0]", "fy_n"), lambda d: effect(d, name="static_load", fx_n=1.0))
    c(
        "effect unknown parameter",
        s + ("effects[0]", "fz_n"),
        lambda d: effect(d, name="static_load", fx_n=1.0, fy_n=0.0, fz_n=1.0),
    )
    c(
        "effect parameter NaN",
        s + ("effects[0]", "finite"),
        lambda d: effect(d, name="static_load", fx_n=float("nan"), fy_n=0.0),
    )
    c(
        "effect parameter text",
        s + ("effects[0]", "fx_n"),
        lambda d: effect(d, name="static_load", fx_n="1 N", fy_n=0.0),
    )
    c("effect axis z", s + ("effects[0]", "axis"), lambda d: effect(d, name="sensor_delay", axis="z", delay_s=1e-5))
    c(
        "sensor delay 1 s",
        s + ("effects[0]", "delay_s"),
        lambda d: effect(d, name="sensor_delay", axis="x", delay_s=1.0),
    )
    c("sensor gain 0", s + ("effects[0]", "gain"), lambda d: effect(d, name="sensor_gain", axis="x", gain=0.0))
    c(
        "dead time 1 ms",
        s + ("effects[0]", "deadtime_s"),
        lambda d: effect(d, name="amplifier_deadtime", deadtime_s=1e-3),
    )
    c(
        "unbalance negative speed",
        s + ("effects[0]", "speed_hz"),
        lambda d: effect(d, name="unbalance", speed_hz=-37.3, mass_ecc_kgm=1e-5),
    )
    c(
        "unbalance speed in rpm",
        s + ("effects[0]", "unbalance", "rpm"),
        lambda d: effect(d, name="unbalance", speed_hz=2238.0, mass_ecc_kgm=3.64e-5, phase_rad=0.8),
    )
    c(
        "static load 1e6 N",
        s + ("effects[0]", "static_load", "capacity"),
        lambda d: effect(d, name="static_load", fx_n=0.0, fy_n=1e6),
    )
    c(
        "static load at the capacity",
        s + ("no levitated equilibrium", "table1.mass_kg"),
        lambda d: effect(d, name="static_load", fx_n=0.0, fy_n=-160.0),
    )
    c(
        "force arrays of unequal length",
        s + ("effects[0]", "fy_n"),
        lambda d: effect(d, name="external_force", t=[0.0, 0.01], fx_n=[0.0, 1.0], fy_n=[0.0]),
    )
    c(
        "force arrays t decreasing",
        s + ("effects[0]", "'t'", "increase"),
        lambda d: effect(d, name="external_force", t=[0.0, 0.01, 0.005], fx_n=[0.0, 1.0, 0.0], fy_n=[0.0] * 3),
    )
    c(
        "force file and arrays",
        s + ("effects[0]", "either"),
        lambda d: (
            existing(d / "force.csv", "t,fx_n,fy_n\n0,0,0\n")
            and effect(d, name="external_force", file="force.csv", t=[0.0], fx_n=[1.0], fy_n=[0.0])
        ),
    )
    f = s + ("effects[0].file", "force.csv")
    head = "t,fx_n,fy_n\n"
    c("force NaN cell", f + ("'fx_n'", "line 3"), lambda d: force_csv(d, head + "0,0,0\n0.005,nan,1\n0.01,0,0\n"))
    c(
        "force text cell",
        f + ("'fx_n'", "line 3", "'abc'"),
        lambda d: force_csv(d, head + "0,0,0\n0.005,abc,1\n0.01,0,0\n"),
    )
    c("force empty cell", f + ("'fy_n'", "line 2"), lambda d: force_csv(d, head + "0,0,\n0.01,0,0\n"))
    c("force infinity", f + ("'fy_n'", "finite"), lambda d: force_csv(d, head + "0,0,inf\n"))
    c("force column missing", f + ("fy_n", "missing"), lambda d: force_csv(d, "t,fx_n\n0,0\n0.01,1\n"))
    c("force unknown column", f + ("fz_n", "unknown"), lambda d: force_csv(d, "t,fx_n,fy_n,fz_n\n0,0,0,0\n"))
    c(
        "force t decreasing",
        f + ("'t'", "increase", "line 4"),
        lambda d: force_csv(d, head + "0,0,0\n0.005,0,1\n0.002,0,0\n"),
    )
    c("force t repeated", f + ("'t'", "increase"), lambda d: force_csv(d, head + "0,0,0\n0.005,0,1\n0.005,0,0\n"))
    c("force file empty", f + ("empty",), lambda d: force_csv(d, ""))
    c("force header only", f + ("no data rows",), lambda d: force_csv(d, head))
    c("force short row", f + ("cells",), lambda d: force_csv(d, head + "0,0\n"))
    c("force semicolons", f + ("not a number",), lambda d: force_csv(d, "t;fx_n;fy_n\n0;0;0\n"))
    c(
        "force binary",
        f + ("UTF-8",),
        lambda d: binary(d / "force.csv") and scenario(d, effects=[{"name": "external_force", "file": "force.csv"}]),
    )
    c(
        "force file missing",
        s + ("effects[0].file", "not found"),
        lambda d: scenario(d, effects=[{"name": "external_force", "file": "gone.csv"}]),
    )
    c(
        "force file a folder",
        s + ("effects[0].file", "folder"),
        lambda d: (d / "fdir.csv").mkdir() or scenario(d, effects=[{"name": "external_force", "file": "fdir.csv"}]),
    )
    c(
        "force beyond the capacity",
        s + ("effects[0]", "external_force", "capacity"),
        lambda d: force_csv(d, head + "0,0,1e6\n0.01,0,1e6\n"),
    )
    return rows


def _npz_cases() -> list[Case]:
    """``closeloop DATA.npz``: the file, its meta, its columns, impossible values."""
    rows = []

    def c(id, names, make):
        rows.append(Case(f"npz {id}", "npz", make, ("d.npz",) + tuple(names)))

    def cut(d, keep):
        p = npz(d)
        b = p.read_bytes()
        p.write_bytes(b[: int(len(b) * keep)])
        return closeloop(d, p)

    def damaged(d):
        p = npz(d)
        b = bytearray(p.read_bytes())
        i = b.index(b"\x93NUMPY", b.index(b"x_meas.npy")) + 300
        b[i : i + 16] = b"\xff" * 16
        p.write_bytes(bytes(b))
        return closeloop(d, p)

    arrays, meta = _demo()
    n = len(arrays["t"])
    c("empty file", ("empty",), lambda d: closeloop(d, existing(d / "d.npz", "")))
    c("cut short", ("readable",), lambda d: cut(d, 0.5))
    c("damaged member", ("readable",), damaged)
    c("a CSV named .npz", ("readable",), lambda d: closeloop(d, existing(d / "d.npz", "t,x\n1,2\n")))
    c("a single .npy array", ("NPZ",), lambda d: closeloop(d, npy(d / "d.npz")))
    c("a folder", ("readable",), lambda d: (d / "d.npz").mkdir() or closeloop(d, d / "d.npz"))
    c("meta not JSON", ("'meta'", "JSON"), lambda d: closeloop(d, npz(d, arrays, raw_meta="{kind: rig")))
    c("meta a list", ("'meta'",), lambda d: closeloop(d, npz(d, arrays, raw_meta="[1, 2]")))
    c(
        "meta settle NaN",
        ("meta key 'settle_s'",),
        lambda d: closeloop(d, npz(d, arrays, {**meta, "settle_s": float("nan")})),
    )
    c(
        "meta seed text",
        ("meta key 'excitation.seed'",),
        lambda d: closeloop(d, npz(d, arrays, {**meta, "excitation": {**meta["excitation"], "seed": "abc"}})),
    )
    c(
        "meta excitation a list",
        ("meta key 'excitation'",),
        lambda d: closeloop(d, npz(d, arrays, {**meta, "excitation": [1]})),
    )
    c(
        "meta start unknown",
        ("meta key 'start'",),
        lambda d: closeloop(d, npz(d, arrays, {**meta, "start": "hovering"})),
    )
    for col in ("fs_hz", "t", "x_meas", "y_ss", "i_xneg", "u_y"):
        c(
            f"column {col} missing",
            (col, "missing"),
            functools.partial(lambda d, col: npz_case(d, **{col: None}), col=col),
        )
    c("NaN in a column", ("'x_meas'", "non-finite"), lambda d: npz_case(d, x_meas=np.r_[arrays["x_meas"][:-1], np.nan]))
    c(
        "infinity in a column",
        ("'i_xneg'", "non-finite"),
        lambda d: npz_case(d, i_xneg=np.r_[np.inf, arrays["i_xneg"][1:]]),
    )
    c("text column", ("'u_x'",), lambda d: npz_case(d, u_x=np.array(["a"] * n)))
    c("complex column", ("'u_y'",), lambda d: npz_case(d, u_y=arrays["u_y"].astype(complex)))
    c("short column", ("'y_ss'",), lambda d: npz_case(d, y_ss=arrays["y_ss"][:-3]))
    c("2-D column", ("'r_x'",), lambda d: npz_case(d, r_x=np.c_[arrays["r_x"], arrays["r_x"]]))
    c("fs_hz NaN", ("'fs_hz'",), lambda d: npz_case(d, fs_hz=np.asarray(np.nan)))
    c("fs_hz text", ("'fs_hz'",), lambda d: npz_case(d, fs_hz=np.asarray("fast")))
    c("fs_hz disagrees with t", ("'fs_hz'", "'t'"), lambda d: npz_case(d, fs_hz=np.asarray(1000.0)))
    c("t not uniform", ("'t'",), lambda d: npz_case(d, t=arrays["t"] ** 1.01))
    c(
        "another sampling rate than the model's",
        ("'fs_hz'", "controller.fs_hz"),
        lambda d: npz_case(d, fs_hz=np.asarray(10000.0), t=np.arange(n) / 10000.0),
    )
    c(
        "too short to split",
        ("too short",),
        lambda d: closeloop(d, npz(d, {k: (v[:8000] if np.ndim(v) else v) for k, v in arrays.items()}, meta)),
    )
    c("optional column with NaN", ("'inj_x'",), lambda d: npz_case(d, inj_x=np.full(n, np.nan), inj_y=np.zeros(n)))
    c("positions in mm", ("'x_meas'", "airgap", "mm"), lambda d: npz_case(d, **scaled(POSITIONS, 1e3)))
    c("positions in um", ("'x_meas'", "airgap"), lambda d: npz_case(d, **scaled(POSITIONS, 1e6)))
    c("currents in mA", ("'i_ypos'", "mA"), lambda d: npz_case(d, **scaled(CURRENTS, 1e3)))
    c("controller outputs in mA", ("'u_x'", "controller.u_max_a"), lambda d: npz_case(d, **scaled(("u_x", "u_y"), 1e3)))
    rows.append(
        Case(
            "npz unknown extension",
            "npz",
            lambda d: closeloop(d, existing(d / "d.mat", "x")),
            ("d.mat", "unknown data format"),
        )
    )
    c("file missing", ("not found",), lambda d: closeloop(d, d / "d.npz"))
    c("read fails (I/O error)", ("readable",), lambda d: closeloop(d, io_error_file(d / "d.npz")))
    c("unreadable (permission)", ("readable",), lambda d: closeloop(d, unreadable(npz(d))))
    return rows


def _csv_cases() -> list[Case]:
    """``closeloop DATA.csv`` and its JSON sidecar."""
    rows = []
    cols = list(CSV_COLUMNS)

    def c(id, names, make):
        rows.append(Case(f"csv {id}", "csv", make, tuple(names)))

    csv_ = ("d.csv",)
    side = ("d.json",)
    _, meta = _demo()
    c("no sidecar", csv_ + ("sidecar",), lambda d: csv(d, text=_csv_text(), sidecar=False))
    c("sidecar malformed", side + ("JSON",), lambda d: csv(d, text=_csv_text(), sidecar='{"fs_hz": 83300, '))
    c("sidecar a list", side + ("object",), lambda d: csv(d, text=_csv_text(), sidecar="[83300]"))
    c(
        "sidecar fs_hz text",
        side + ("'fs_hz'",),
        lambda d: csv(d, text=_csv_text(), sidecar={"fs_hz": "fast", "meta": meta}),
    )
    c("sidecar fs_hz NaN", side + ("'fs_hz'", "finite"), lambda d: csv(d, text=_csv_text(), sidecar='{"fs_hz": NaN}'))
    c("sidecar fs_hz boolean", side + ("'fs_hz'",), lambda d: csv(d, text=_csv_text(), sidecar={"fs_hz": True}))
    c(
        "sidecar without fs_hz",
        side + ("'fs_hz'", "missing"),
        lambda d: csv(d, text=_csv_text(), sidecar={"meta": meta}),
    )
    c(
        "sidecar meta not JSON",
        side + ("'meta'",),
        lambda d: csv(d, text=_csv_text(), sidecar={"fs_hz": 83300.0, "meta": "{k"}),
    )
    c(
        "sidecar meta NaN",
        side + ("settle_s", "finite"),
        lambda d: csv(d, text=_csv_text(), sidecar='{"fs_hz": 83300.0, "meta": {"settle_s": NaN}}'),
    )
    c("sidecar a folder", ("d.json",), lambda d: (d / "d.json").mkdir() or csv(d, text=_csv_text(), sidecar=False))
    c("empty", csv_ + ("empty",), lambda d: csv(d, text=""))
    c("header only", csv_ + ("no data rows",), lambda d: csv(d, text=",".join(cols) + "\n"))
    c("text cell", csv_ + ("'y_ss'", "'abc'"), lambda d: csv(d, text=_cell(6, "y_ss", "abc")))
    c("empty cell", csv_ + ("'y_ss'",), lambda d: csv(d, text=_cell(6, "y_ss", "")))
    c("NaN cell", csv_ + ("'y_ss'", "non-finite"), lambda d: csv(d, text=_cell(6, "y_ss", "nan")))
    c("short row", csv_ + ("line 6",), lambda d: csv(d, text=_cell(6, "y_ss", "1,2")))
    c("repeated column", csv_ + ("'t'", "more than once"), lambda d: csv(d, text=",".join(cols + ["t"]) + "\n1\n"))
    c(
        "binary",
        csv_ + ("UTF-8",),
        lambda d: (
            existing(d / "d.json", json.dumps({"fs_hz": 83300.0, "meta": meta})),
            closeloop(d, binary(d / "d.csv")),
        )[1],
    )
    c(
        "a folder",
        csv_ + ("cannot be read",),
        lambda d: (
            (d / "d.csv").mkdir(),
            (d / "d.json").write_text(json.dumps({"fs_hz": 83300.0})),
            closeloop(d, d / "d.csv"),
        )[2],
    )
    c(
        "read fails (I/O error)",
        csv_ + ("cannot be read",),
        lambda d: (
            existing(d / "d.json", json.dumps({"fs_hz": 83300.0, "meta": meta})),
            closeloop(d, io_error_file(d / "d.csv")),
        )[1],
    )
    c(
        "unreadable (permission)",
        csv_ + ("cannot be read",),
        lambda d: (
            existing(d / "d.json", json.dumps({"fs_hz": 83300.0, "meta": meta})),
            closeloop(d, unreadable(existing(d / "d.csv", _csv_text()))),
        )[1],
    )
    c(
        "column missing",
        csv_ + ("y_ss", "missing"),
        lambda d: csv(
            d,
            text="\n".join(
                ",".join(p for i, p in enumerate(ln.split(",")) if i != 5) for ln in _csv_text().splitlines()
            )
            + "\n",
        ),
    )
    c(
        "fs_hz as a column",
        csv_ + ("'fs_hz'",),
        lambda d: csv(
            d,
            text="".join(
                ("fs_hz," if i == 0 else "83300.0,") + ln + "\n" for i, ln in enumerate(_csv_text().splitlines())
            ),
        ),
    )
    c("semicolons", csv_ + ("not a number",), lambda d: csv(d, text=_csv_text().replace(",", ";")))
    c(
        "positions in mm",
        csv_ + ("'x_meas'", "airgap"),
        lambda d: csv(d, arrays={**_demo()[0], **scaled(POSITIONS, 1e3)}),
    )
    return rows


@functools.lru_cache(maxsize=None)
def _cell(line: int, col: str, value: str) -> str:
    lines = _csv_text().splitlines()
    cells = lines[line - 1].split(",")
    cells[CSV_COLUMNS.index(col)] = value
    lines[line - 1] = ",".join(cells)
    return "\n".join(lines) + "\n"


def _cli_cases() -> list[Case]:
    """The command line and where its outputs go."""
    rows = []

    def c(id, names, make, area="output"):
        rows.append(Case(id, area, make, tuple(names)))

    sc = lambda d: scenario(d)[1]  # noqa: E731  a valid scenario file

    for cmd in ("simulate", "rig"):

        def argv(d, out, cmd=cmd, *extra):
            base = simulate(d) if cmd == "simulate" else ["rig", sc(d), "--out", d / "rig.npz", "--quiet"]
            i = base.index("--out")
            return base[: i + 1] + [out] + base[i + 2 :] + list(extra)

        c(
            f"{cmd} --out not .npz",
            ("--out", "x.txt", ".npz"),
            functools.partial(lambda d, a: a(d, d / "x.txt"), a=argv),
        )
        c(
            f"{cmd} --out under a file",
            ("--out", "afile", "not a folder"),
            functools.partial(lambda d, a: a(d, existing(d / "afile") / "x.npz"), a=argv),
        )
        c(
            f"{cmd} --out a folder",
            ("--out", "x.npz", "folder"),
            functools.partial(lambda d, a: (d / "x.npz").mkdir() or a(d, d / "x.npz"), a=argv),
        )
        c(
            f"{cmd} --out whose sidecar is a folder",
            ("--out", "x.json", "folder"),
            functools.partial(lambda d, a: (d / "x.json").mkdir() or a(d, d / "x.npz"), a=argv),
        )
        c(
            f"{cmd} --out exists",
            ("--out", "x.npz", "--force"),
            functools.partial(lambda d, a: a(d, existing(d / "x.npz").with_suffix(".npz")), a=argv),
        )
        c(
            f"{cmd} --out next to the user's data.json",
            ("--out", "data.json", "--force"),
            functools.partial(
                lambda d, a: (
                    existing(d / "data.csv"),
                    existing(d / "data.json", '{"fs_hz": 1}'),
                    a(d, d / "data.npz"),
                )[2],
                a=argv,
            ),
        )
        c(
            f"{cmd} --out into a read-only folder",
            ("--out", "ro", "cannot write"),
            functools.partial(lambda d, a: a(d, readonly(d / "ro") / "x.npz"), a=argv),
        )
        c(
            f"{cmd} --out under a read-only folder",
            ("--out", "ro", "cannot write"),
            functools.partial(lambda d, a: a(d, readonly(d / "ro") / "sub" / "x.npz"), a=argv),
        )
    data = lambda d: npz(d)  # noqa: E731
    c(
        "closeloop --out a file",
        ("--out", "afile"),
        lambda d: closeloop(d, data(d))[:2] + ["--out", existing(d / "afile")],
    )
    c(
        "closeloop --out with foreign files",
        ("--out", "notes.txt"),
        lambda d: (existing(d / "out" / "notes.txt"), closeloop(d, data(d)))[1],
    )
    c(
        "closeloop --out with a previous analysis",
        ("--out", "--force"),
        lambda d: (existing(d / "out" / "closeloop.json", "{}"), closeloop(d, data(d)))[1],
    )
    c(
        "closeloop --out into a read-only folder",
        ("--out", "cannot write"),
        lambda d: closeloop(d, data(d))[:2] + ["--out", readonly(d / "ro") / "out", "--quiet"],
    )
    c(
        "closeloop --out a read-only previous output",
        ("--out", "cannot write"),
        lambda d: (
            existing(d / "ro" / "out" / "closeloop.json", "{}"),
            closeloop(d, data(d))[:2] + ["--out", readonly(d / "ro") / "out", "--force", "--quiet"],
        )[1],
    )
    c("closeloop --workers 0", ("--workers",), lambda d: closeloop(d, data(d))[:-1] + ["0"], area="cli")
    c("closeloop --workers text", ("--workers",), lambda d: closeloop(d, data(d))[:-1] + ["two"], area="cli")
    c(
        "simulate unknown experiment",
        ("nope",),
        lambda d: ["simulate", "--experiment", "nope", "--out", d / "x.npz"],
        area="cli",
    )
    c("simulate without --out", ("--out",), lambda d: ["simulate", "--experiment", "levitate"], area="cli")
    c("rig without a scenario", ("scenario",), lambda d: ["rig", "--out", d / "x.npz"], area="cli")
    c("unknown command", ("fly",), lambda d: ["fly"], area="cli")
    c("unknown option", ("--colour",), lambda d: simulate(d, "--colour", "red"), area="cli")
    cl = lambda d, **e: closeloop(d, data(d), "--config", config_file(d, **e))  # noqa: E731
    c(
        "closeloop --config unknown calibration key",
        ("c.yaml", "closeloop.calibration.table1.mass_kgg"),
        lambda d: cl(d, closeloop__calibration={"table1.mass_kgg": 0.03}),
        area="config",
    )
    c(
        "closeloop --config calibration of a text key",
        ("c.yaml", "closeloop.calibration.magnetics.eddy_model"),
        lambda d: cl(d, closeloop__calibration={"magnetics.eddy_model": 0.03}),
        area="config",
    )
    c(
        "closeloop --config calibration tolerance 0",
        ("c.yaml", "closeloop.calibration"),
        lambda d: cl(d, closeloop__calibration={"table1.mass_kg": 0.0}),
        area="config",
    )
    c(
        "closeloop --config fit fraction 2",
        ("c.yaml", "closeloop.fit_fraction"),
        lambda d: cl(d, closeloop__fit_fraction=2.0),
        area="config",
    )
    c(
        "closeloop --config unknown key",
        ("c.yaml", "closeloop", "fit_fractions"),
        lambda d: cl(d, closeloop__fit_fractions=0.5),
        area="config",
    )
    c(
        "closeloop --config unknown estimate key",
        ("c.yaml", "closeloop.estimate", "iterations"),
        lambda d: cl(d, closeloop__estimate={"iterations": 3}),
        area="config",
    )
    c(
        "closeloop --config default dataset not listed",
        ("c.yaml", "closeloop.default_dataset"),
        lambda d: cl(d, closeloop__default_dataset="nope"),
        area="config",
    )
    c(
        "closeloop --config binary",
        ("b.yaml", "UTF-8"),
        lambda d: closeloop(d, data(d), "--config", binary(d / "b.yaml")),
        area="config",
    )
    c(
        "closeloop --config duplicate key",
        ("c.yaml", "closeloop.replay_seeds", "twice"),
        lambda d: closeloop(
            d,
            data(d),
            "--config",
            config_file(
                d, text=replace_once(CONFIG_TEXT, "\ncloseloop:", "\ncloseloop:\n  replay_seeds: 4\n  replay_seeds: 5")
            ),
        ),
        area="config",
    )
    return rows


def _note_cases() -> list[Case]:
    """Valid but suspicious data: close the loop's notes, before it fits anything."""
    arrays, _ = _demo()
    n = len(arrays["t"])
    rows = []

    def c(id, names, **changes):
        rows.append(
            Case(
                f"note {id}", "note", functools.partial(lambda d, ch: demo(**ch), ch=changes), tuple(names), kind="note"
            )
        )

    a = arrays
    c("x and y positions swapped", ("'x_meas'", "'y_meas'", "swapped"), x_meas=a["y_meas"], y_meas=a["x_meas"])
    c("y_ss follows x", ("'y_ss'", "swapped"), y_ss=a["x_meas"])
    c(
        "x and y currents swapped",
        ("'i_xpos'", "swapped"),
        i_xpos=a["i_ypos"],
        i_xneg=a["i_yneg"],
        i_ypos=a["i_xpos"],
        i_yneg=a["i_xneg"],
    )
    c("upper and lower coils swapped", ("'i_ypos'", "'i_yneg'", "swapped"), i_ypos=a["i_yneg"], i_yneg=a["i_ypos"])
    c("controller outputs swapped", ("'u_x'", "'u_y'", "swapped"), u_x=a["u_y"], u_y=a["u_x"])
    c("constant y_ss", ("'y_ss'", "constant"), y_ss=np.full(n, 2e-6))
    c("probe that never moves", ("'x_meas'", "never moves"), x_meas=a["x_meas"] * 1e-5)
    c("clipped current", ("'i_ypos'", "clipped"), i_ypos=np.minimum(a["i_ypos"], 4.2))
    c("clipped position", ("'y_meas'", "clipped"), y_meas=np.clip(a["y_meas"], -3e-5, 3e-5))
    c("controller output held at its clamp", ("'u_y'", "clipped"), u_y=np.minimum(a["u_y"], 1.0))
    c("currents in kA", ("'i_ypos'", "bias"), **scaled(CURRENTS, 1e-3))
    c("positions beyond the clearance", ("'y_meas'", "clearance"), y_meas=a["y_meas"] * 10.0)
    c("constant current", ("'i_xneg'", "constant"), i_xneg=np.full(n, 3.0))
    # levitation at rest is analysed (slow trends, noise spectra), with a note that nothing excites it
    c("no excitation (all zero)", ("'r_x'", "'r_y'", "constant", "nothing excites"), r_x=np.zeros(n), r_y=np.zeros(n))
    return rows


# ------------------------------------------------------------------------------------------
# the workflow (a copy of the repository per session; every row a separate config file)
def _workflow_cases() -> list[Case]:
    rows = []

    def c(id, names, make, status=2, log=None):
        rows.append(Case(f"workflow {id}", "workflow", make, tuple(names), kind="workflow", status=status, log=log))

    def extra(text):
        def make(wd):
            (wd / "bad.yaml").write_text(text)
            return ["-n", "--cores", "1", "--configfile", "config.yaml", "bad.yaml"]

        return make

    def dup(wd):
        (wd / "dup.yaml").write_text(replace_once(CONFIG_TEXT, "  mass_kg: 3.86", "  mass_kg: 3.86\n  mass_kg: 3.96"))
        return ["-n", "--cores", "1", "--configfile", "dup.yaml"]

    def nan_data(wd):
        z = dict(np.load(DEMO))
        z["x_meas"] = z["x_meas"].copy()
        z["x_meas"][100] = np.nan
        np.savez(wd / "bad.npz", **z)
        (wd / "bad.yaml").write_text("closeloop: {datasets: {bad: bad.npz}, default_dataset: bad}\n")
        return ["results/closeloop/bad/closeloop.json", "--cores", "1", "--configfile", "config.yaml", "bad.yaml"]

    c("duplicate key in a config file", ("dup.yaml", "table1.mass_kg", "twice"), dup)
    c("airgap in mm", ("bad.yaml", "table1.airgap_m", "plausible"), extra("table1: {airgap_m: 0.6}\n"))
    c("NaN in a config file", ("bad.yaml", "table1.mass_kg", "finite"), extra("table1: {mass_kg: .nan}\n"))
    c("unknown key", ("bad.yaml", "table1", "mass_kgs"), extra("table1: {mass_kgs: 3.0}\n"))
    c(
        "scenario override airgap in mm",
        ("run 'wide'", "table1.airgap_m", "plausible"),
        extra("scenarios: {wide: {table1.airgap_m: 0.6}}\n"),
    )
    c(
        "scenario override of no key",
        ("wide", "table1.airgap_mm"),
        extra("scenarios: {wide: {table1.airgap_mm: 0.6}}\n"),
    )
    c(
        "study value in mm",
        ("airgap=0.6", "table1.airgap_m"),
        extra(
            "study: {assumptions: {airgap: {key: table1.airgap_m, values: [0.6]}}, "
            "criteria: {mu_peak_factor: 1.5, fit_y_points: 5}}\n"
        ),
    )
    c(
        "duration 1e9 s",
        ("experiments.levitate.duration_s", "samples"),
        extra("experiments: {levitate: {duration_s: 1.0e+9, start: rest, excitation: {kind: none}}}\n"),
    )
    c(
        "closeloop calibration of no key",
        ("closeloop.calibration.table1.mass_kgg",),
        extra("closeloop: {calibration: {table1.mass_kgg: 0.03}}\n"),
    )
    c(
        "closeloop data set not found",
        ("closeloop.datasets.gone", "gone.npz"),
        extra("closeloop: {datasets: {gone: gone.npz}, default_dataset: gone}\n"),
    )
    c(
        "rig recording not found",
        ("closeloop.rigs.maglev1d.hold.gone", "gone.npz"),
        extra("closeloop: {rigs: {maglev1d: {device: maglev1d, config: null, fit: {escalon: "
              "resources/maglev1d/dataset_escalon_20251217_205858.npz}, hold: {gone: gone.npz}}}}\n"),
    )
    c(
        "rig of an unknown device",
        ("closeloop.rigs.maglev1d", "levitron"),
        extra("closeloop: {rigs: {maglev1d: {device: levitron, config: null, fit: {escalon: "
              "resources/maglev1d/dataset_escalon_20251217_205858.npz}, hold: {multiescalon: "
              "resources/maglev1d/dataset_multiescalon_20251217_210203.npz}}}}\n"),
    )
    c(
        "closeloop data with NaN: the failed job's log",
        ("bad.npz", "'x_meas'", "non-finite"),
        nan_data,
        status=1,
        log="results/logs/closeloop/bad.log",
    )
    return rows


def all_cases() -> list[Case]:
    rows = (
        _cfg_cases()
        + _set_cases()
        + _scenario_cases()
        + _npz_cases()
        + _csv_cases()
        + _cli_cases()
        + _note_cases()
        + _workflow_cases()
    )
    ids = [r.id for r in rows]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    assert not dup, dup
    return rows


# ------------------------------------------------------------------------------------------
# running a row
def _snapshot(folder: Path) -> dict:
    out = {}
    for p in sorted(folder.rglob("*")):
        try:
            if p.is_symlink() or not p.is_file():
                out[str(p)] = "dir" if p.is_dir() else "link"
            else:
                out[str(p)] = hashlib.sha256(p.read_bytes()).hexdigest()
        except OSError:
            out[str(p)] = "unreadable"
    return out


def _verdict(case: Case, status, err: str, before: dict, after: dict) -> tuple[str, str]:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if "Traceback" in err:
        return "traceback", err[-2000:]
    if status == 0:
        return "accepted", err[-500:] or "exit 0"
    if status != case.status:
        return "wrong status", f"exit {status}: {err[-500:]}"
    if len(lines) != 1:
        return "not one line", err[-1000:]
    missing = [n for n in case.names if n not in lines[0]]
    if missing:
        return "unnamed", f"{missing} not in: {lines[0]}"
    if before != after:
        changed = sorted(set(after) ^ set(before) | {k for k in before if after.get(k) != before[k]})
        return "wrote files", ", ".join(Path(c).name for c in changed[:5])
    return "ok", lines[0]


def _run_cli(case: Case, folder: Path, subprocess_cli: bool) -> Outcome:
    from ssamb.cli import main

    argv = [str(a) for a in case.make(folder)]
    before = _snapshot(folder)
    if subprocess_cli:
        r = subprocess.run([sys.executable, "-m", "ssamb", *argv], capture_output=True, text=True, cwd=folder)
        status, err = r.returncode, r.stderr
    else:
        out, err_io = io.StringIO(), io.StringIO()
        # warnings logged during the command reach its stderr, as they do at the command line
        # (under pytest the root logger has handlers of its own, and the last resort is unused)
        handler = logging.StreamHandler(err_io)
        handler.setLevel(logging.WARNING)
        logging.getLogger().addHandler(handler)
        try:
            with redirect_stderr(err_io), redirect_stdout(out):
                status = main(argv)
        except SystemExit as exc:
            status = exc.code if isinstance(exc.code, int) else 1
        except Exception:  # a traceback at the command line
            return Outcome(case, "traceback", traceback.format_exc()[-2000:])
        finally:
            logging.getLogger().removeHandler(handler)
        err = err_io.getvalue()
    verdict, detail = _verdict(case, status, err, before, _snapshot(folder))
    return Outcome(case, verdict, detail)


def _run_note(case: Case) -> Outcome:
    from ssamb.config import load_config
    from ssamb.io import validate_measured
    from ssamb.plausibility import check_measured, measured_notes

    arrays, meta = case.make(None)
    cfg = load_config()
    try:
        validate_measured(arrays, "d.npz")
        check_measured(arrays, cfg, "d.npz", meta)
    except Exception as exc:  # a note case holds valid, possible data
        return Outcome(case, "wrong status", f"rejected: {exc}")
    notes = measured_notes(arrays, meta, cfg)
    hit = [n for n in notes if all(w in n for w in case.names)]
    if not hit:
        return Outcome(case, "accepted" if not notes else "unnamed", "; ".join(notes) or "no note")
    return Outcome(case, "ok", hit[0])


SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def workflow_copy(folder: Path) -> Path:
    """A copy of what the workflow needs (Snakefile, config, workflow/, resources/) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("Snakefile", "config.yaml"):
        shutil.copy(REPO / name, folder / name)
    for d in ("workflow", "resources"):
        if not (folder / d).exists():
            shutil.copytree(REPO / d, folder / d, ignore=shutil.ignore_patterns("__pycache__", ".snakemake"))
    return folder


def _run_workflow(case: Case, wd: Path) -> Outcome:
    shutil.rmtree(wd / "results", ignore_errors=True)
    args = case.make(wd)
    r = subprocess.run(SNAKEMAKE + [str(a) for a in args], cwd=wd, capture_output=True, text=True)
    text = r.stdout + r.stderr
    if "Traceback" in text:
        return Outcome(case, "traceback", text[-2000:])
    if r.returncode == 0:
        return Outcome(case, "accepted", text[-500:])
    if r.returncode != case.status:
        return Outcome(case, "wrong status", f"exit {r.returncode}: {text[-800:]}")
    if case.log is None:
        lines = [ln for ln in r.stderr.splitlines() if ln.strip() and "is extended by additional config" not in ln]
        if len(lines) != 1:
            return Outcome(case, "not one line", r.stderr[-1000:])
        line = lines[0]
        if (wd / "results").exists():
            return Outcome(case, "wrote files", "results/ exists")
    else:
        log = wd / case.log
        line = log.read_text() if log.exists() else ""
        if not line:
            return Outcome(case, "unnamed", f"{case.log} empty or missing")
        outputs = [
            p
            for p in (wd / "results").rglob("*")
            if p.is_file() and "logs" not in p.parts and "benchmarks" not in p.parts
        ]
        if outputs:
            return Outcome(case, "wrote files", ", ".join(p.name for p in outputs[:5]))
    missing = [n for n in case.names if n not in line]
    if missing:
        return Outcome(case, "unnamed", f"{missing} not in: {line}")
    return Outcome(case, "ok", line.strip())


def run_case(case: Case, folder: Path, workflow_dir: Path | None = None, subprocess_cli: bool = False) -> Outcome:
    """Run one row in the (empty) ``folder``; a ``workflow`` row runs in ``workflow_dir`` (a
    :func:`workflow_copy`). Returns its :class:`Outcome`."""
    try:
        if case.kind == "note":
            return _run_note(case)
        if case.kind == "workflow":
            return _run_workflow(case, workflow_dir or workflow_copy(folder / "wf"))
        return _run_cli(case, folder, subprocess_cli)
    except _Skip as exc:
        return Outcome(case, "skipped", str(exc))
    finally:
        release(folder)
