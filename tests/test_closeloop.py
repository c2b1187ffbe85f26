"""Tests of the close-the-loop analysis: bad data, output files and format, the building blocks."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPLAY_WORKERS

from ssamb.cli import main
from ssamb.closeloop import run_closeloop
from ssamb.closeloop.data import Record, make_split
from ssamb.closeloop.residual import _ratio_fit
from ssamb.closeloop.settings import Settings, settings_from_config
from ssamb.closeloop.spectra import dft, find_peaks_bins, fit_line, lasts, make_frame, noise_floor, white_sigma
from ssamb.config import load_config
from ssamb.io import DataError, MEASURED_COLUMNS, save_npz
from ssamb.rig import run_scenario

REPO = Path(__file__).resolve().parent.parent
FS = 83300.0


def _arrays(n: int, fs: float = FS) -> dict:
    rng = np.random.default_rng(0)
    a = {c: 1e-6 * rng.standard_normal(n) for c in MEASURED_COLUMNS}
    a["t"] = np.arange(n) / fs
    a["fs_hz"] = np.asarray(fs)
    return a


def _write(tmp: Path, arrays: dict, name: str = "d.npz") -> Path:
    p = tmp / name
    save_npz(p, arrays, {"excitation": {"kind": "none"}})
    return p


@pytest.mark.parametrize("break_it, message", [
    (lambda a: a.pop("y_ss"), "missing required column.*y_ss"),
    (lambda a: a["x_meas"].__setitem__(100, np.nan), "x_meas.*non-finite"),
    (lambda a: a.__setitem__("fs_hz", np.asarray(50000.0)), "fs_hz.*disagrees"),
])
def test_bad_data_clear_error_and_nothing_written(tmp_path, break_it, message):
    a = _arrays(int(0.5 * FS))
    break_it(a)
    p = _write(tmp_path, a)
    out = tmp_path / "out"
    with pytest.raises(DataError, match=message):
        run_closeloop(p, out, progress=False)
    assert not out.exists()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["d.json", "d.npz"]


def test_data_at_another_rate_than_the_model(tmp_path):
    fs = 41650.0
    p = _write(tmp_path, _arrays(int(0.5 * fs), fs))
    with pytest.raises(DataError, match="differs from the model's controller rate"):
        run_closeloop(p, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_too_short_to_split(tmp_path, capsys):
    p = _write(tmp_path, _arrays(int(0.2 * FS)))
    with pytest.raises(DataError, match="too short to split"):
        run_closeloop(p, tmp_path / "out", progress=False)
    # the command line: exit 2, one line naming the problem, nothing written
    assert main(["closeloop", str(p), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "too short to split" in err[0]
    assert not (tmp_path / "out").exists()


def test_csv_without_sidecar(tmp_path):
    p = tmp_path / "d.csv"
    p.write_text(",".join(MEASURED_COLUMNS) + "\n" + ",".join("0" for _ in MEASURED_COLUMNS) + "\n")
    with pytest.raises(DataError, match="sidecar"):
        run_closeloop(p, tmp_path / "out", progress=False)


def test_settings_unknown_key():
    with pytest.raises(ValueError, match="closeloop.fit_fractoin"):
        settings_from_config({"closeloop": {"fit_fractoin": 0.5}})
    assert settings_from_config({"closeloop": {"datasets": {"a": "b"}, "fit_fraction": 0.6}}).fit_fraction == 0.6


def test_split_on_whole_periods():
    n_p = 16660
    rec = Record(device=None, fs_hz=FS, channels={"x_meas": np.zeros(6 * n_p)}, inputs={}, excitation={},
                 excited_axes=("y",), signal={}, n_period=n_p, lines_hz=None, start="levitated", settle_s=None)
    sp = make_split(rec, 0.7, 0.1, 0.1, 0.05)
    assert (sp.i0, sp.i_fit, sp.i_end) == (n_p, 4 * n_p, 6 * n_p)   # 1 discarded, 3 fitted, 2 held out
    rec2 = Record(device=None, fs_hz=FS, channels={"x_meas": np.zeros(int(0.5 * FS))}, inputs={}, excitation={},
                  excited_axes=(), signal={}, n_period=None, lines_hz=None, start="levitated", settle_s=None)
    sp2 = make_split(rec2, 0.7, 0.1, 0.1, 0.05)
    assert abs(sp2.fit_fraction - 0.7) < 1e-3 and sp2.i0 == math.ceil(0.1 * FS)


def _signal_with_lines(n, sigma, lines, rng):
    t = np.arange(n) / FS
    x = sigma * rng.standard_normal(n)
    for f, a, ph in lines:
        x += a * np.cos(2 * np.pi * f * t + ph)
    return x


@pytest.mark.parametrize("periodic", [True, False])
def test_noise_floor_and_lines(periodic):
    rng = np.random.default_rng(1)
    n_p = 16660
    n = 4 * n_p
    # excited lines on the grid (periodic case) + one line the excitation lacks
    exc = _signal_with_lines(n, 0.0, [(5.0 * k, 1.0, 0.3 * k) for k in range(1, 21)], rng)
    # the line: between the excited lines (periodic frame), above the excited band otherwise (a
    # Hann frame cannot tell a line from the excitation's own lines closer than its main lobe)
    fl = 37.31 if periodic else 137.31
    x = _signal_with_lines(n, 2e-4, [(5.0 * k, 3e-3, 0.1 * k) for k in range(1, 21)] + [(fl, 2e-3, 0.7)], rng)
    fr = make_frame(FS, 0, n, {"y": exc}, n_p if periodic else None, np.arange(5.0, 101.0, 5.0) if periodic else None)
    if not periodic:
        x = x - _signal_with_lines(n, 0.0, [(5.0 * k, 3e-3, 0.1 * k) for k in range(1, 21)], rng)
    X = dft(fr, x)
    S = noise_floor(fr, X)
    cl = find_peaks_bins(fr, {"v": np.abs(X) ** 2}, {"v": S}, 0, 500, 1e-3)
    assert len(cl) == 1 and abs(cl[0]["f_hz"] - fl) < 2 * fr.df_hz
    ln = fit_line(fr, {"v": x}, {"v": 2e-4}, cl[0]["f_hz"])
    assert abs(ln["f_hz"] - fl) < 2e-3
    assert abs(abs(ln["phasor"]["v"]) / 2e-3 - 1) < 0.02
    assert abs(np.angle(ln["phasor"]["v"]) - 0.7) < 0.02
    # with the line removed the floor is the noise (a rectangular frame leaks the line off-grid)
    S = noise_floor(fr, dft(fr, x - ln["component"]["v"]))
    assert abs(white_sigma(fr, S) / 2e-4 - 1) < 0.05


def test_a_line_inside_a_sweeps_range_is_searched_and_a_multisines_lines_are_not():
    """A Hann frame's line search skips the excitation's own narrow lines that last through the
    segment (a multisine's), not a sweep's range, which it passes once: a 39.6 Hz line beside a
    6-63 Hz linear sweep (0.75 s, the suite's draw kind) is found; a 12-30 Hz sweep, which stands
    as narrow lines against its band's median, has its range searched and marked as passing; a
    non-periodic multisine's lines (20 Hz apart: 15 bins) stay out of the search."""
    rng = np.random.default_rng(3)
    n = int(0.75 * FS)
    t = np.arange(n) / FS
    f0, f1 = 6.0, 63.0
    sweep = np.sin(2 * np.pi * (f0 * t + 0.5 * (f1 - f0) / t[-1] * t ** 2))
    fr = make_frame(FS, 0, n, {"x": sweep}, None, None)
    band = (fr.f_hz > 10) & (fr.f_hz < 60)
    assert fr.line_mask[band].all()
    narrow = np.sin(2 * np.pi * (12.0 * t + 0.5 * (30.0 - 12.0) / t[-1] * t ** 2))
    fn = make_frame(FS, 0, n, {"x": narrow}, None, None)
    inside = (fn.f_hz > 14) & (fn.f_hz < 28)
    assert fn.line_mask[inside].all() and fn.passing_mask[inside].all() and not fn.passing_mask[fn.f_hz > 100].any()
    x = 2e-4 * rng.standard_normal(n) + 3e-3 * np.cos(2 * np.pi * 39.6 * t + 0.4)
    X = dft(fr, x)
    cl = find_peaks_bins(fr, {"v": np.abs(X) ** 2}, {"v": noise_floor(fr, X)}, 0, 500, 1e-3)
    assert len(cl) == 1 and abs(cl[0]["f_hz"] - 39.6) < 2 * fr.df_hz
    ms = _signal_with_lines(n, 0.0, [(20.0 * k, 1.0, 0.3 * k) for k in range(1, 11)], rng)
    fr = make_frame(FS, 0, n, {"x": ms}, None, None)
    on = np.array([np.argmin(np.abs(fr.f_hz - 20.0 * k)) for k in range(1, 11)])
    assert not fr.line_mask[on].any() and not fr.passing_mask.any()


@pytest.mark.parametrize("amplitude", [3e-4, 3e-3])
def test_a_line_lasts_through_the_segment_and_a_transient_does_not(amplitude):
    """:func:`ssamb.closeloop.spectra.lasts`: a 39.6 Hz sinusoid throughout 0.75 s of white noise
    (at the detection threshold and well above it) lasts; the same frequency as a burst of 0.1 s
    in the second quarter (a sweep passing a misplaced resonance) does not."""
    rng = np.random.default_rng(5)
    n = int(0.75 * FS)
    t = np.arange(n) / FS
    fr = make_frame(FS, 0, n, {}, None, None)
    noise = 2e-4 * rng.standard_normal(n)
    steady = noise + amplitude * np.cos(2 * np.pi * 39.6 * t + 0.4)
    burst = noise + 10 * amplitude * np.cos(2 * np.pi * 39.6 * t) * ((t > 0.25) & (t < 0.35))
    assert lasts(fr, steady, 39.6)
    assert not lasts(fr, burst, 39.6)


def test_ratio_fit_recovers_gain_and_delay():
    rng = np.random.default_rng(2)
    f = np.arange(5.0, 101.0, 5.0)
    w = 2 * np.pi * f
    Hh_s = 1.0 / (1 + 1j * f / 30.0)
    Hh_a = np.ones_like(Hh_s) * 0.5
    var = 1e-8 * np.ones_like(f)

    def noise():
        return np.sqrt(var / 2) * (rng.standard_normal(len(f)) + 1j * rng.standard_normal(len(f)))

    Hm_s = 1.05 * np.exp(-1j * w * 2.0e-5) * Hh_s + noise()
    Hm_a = Hh_a + noise()
    r = _ratio_fit(f, Hm_s, Hm_a, Hh_s, Hh_a, var, var)
    assert abs(r["gain"] - 1.05) < 1e-3 and abs(r["tau_s"] - 2e-5) < 2e-7
    assert r["z_tau"] > 10 and r["z_alpha"] > 10


#: a lighter analysis for the format tests: fewer replays and calibrated parameters
LIGHT = {"replay_seeds": 4, "estimate": {"centre_runs": 3, "max_iter": 6},
         "calibration": {"table1.i_bias_a": 0.03, "selfsensing.calibration_gain_error": 0.03,
                         "selfsensing.calibration_offset_error_m": 1.0e-5}}


#: lighter still, for a test of how the replays run rather than of what the analysis finds: one
#: calibrated parameter, one candidate per round and one effect, one iteration of every fit
LIGHTEST = {**LIGHT, "replay_seeds": 2, "estimate": {"centre_runs": 2, "max_iter": 2}, "max_effects": 1,
            "calibration": {"table1.i_bias_a": 0.03},
            "candidates_per_round": 1, "candidate_iterations": 1, "joint_iterations": 1}


def _light_config(tmp: Path, settings: dict = LIGHT) -> Path:
    """``tmp/c.yaml``: the repository's config with a light analysis (``settings``) and no data sets."""
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    cfg["closeloop"].update(settings)
    cfg["closeloop"]["datasets"] = {}
    cfg["closeloop"].pop("default_dataset", None)
    (tmp / "c.yaml").write_text(yaml.safe_dump(cfg))
    return tmp / "c.yaml"


@pytest.fixture
def written(row5) -> Path:
    """A close-the-loop analysis written as the command line writes it: row 5 of issue 23's
    table (tests/conftest.py ``row5``: a sensor delay and a static load found on a rig)."""
    return row5["out"]


@pytest.mark.slow
def test_the_result_does_not_depend_on_the_workers(tmp_path):
    """One analysis on two processes and on one: byte-identical reports, written as
    ``closeloop.json`` is written (every replay is seeded).

    The smallest analysis that takes every path the replays run in parallel: a 0.3 s multisine
    on both axes (20-100 Hz) of a rig with a 30 us y sensor delay, the lightest settings (one
    iteration of each fit, one candidate). Its search fits a candidate (the estimator's batches of
    replays, and the seeds of a prediction), the sensor delay, whose whole-sample aliases are
    replayed in one batch; what it finds does not matter here, only that both runs agree bit for
    bit. The record's length, the lines and the iterations do not change which code runs, only how
    long it takes."""
    from ssamb.closeloop import analyse
    from ssamb.device import get_device
    from ssamb.io import write_json

    cfg = load_config(_light_config(tmp_path, LIGHTEST))
    sc = tmp_path / "s.yaml"
    sc.write_text(yaml.safe_dump({
        "config": str(REPO / "config.yaml"),
        "experiment": {"kind": "multisine", "point": "position", "axis": "both", "amplitude_m": 3.0e-5,
                       "f_min_hz": 20, "f_max_hz": 100, "f_resolution_hz": 20, "periods": 6, "seed": 3},
        "effects": [{"name": "sensor_delay", "axis": "y", "delay_s": 30e-6}],
        "noise": {"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": 5}}))
    data = tmp_path / "rig.npz"
    run_scenario(sc, data, progress=False)
    arrays, meta = get_device("amb").load(data)
    for workers in (2, 1):
        write_json(tmp_path / f"{workers}.json", analyse(arrays, meta, cfg, workers=workers))
    two, one = ((tmp_path / f"{w}.json").read_text() for w in (2, 1))
    rounds = json.loads(two)["rounds"]
    assert any(c["name"] == "sensor_delay" for r in rounds for c in r["candidates"]), rounds
    assert two == one


@pytest.mark.slow
def test_closeloop_json_binding_format(written):
    rep = json.loads((written / "closeloop.json").read_text())
    assert isinstance(rep["effects"], list) and isinstance(rep["unexplained"], bool)
    for e in rep["effects"]:
        assert set(e) >= {"name", "params", "error_reduction", "evidence"} and isinstance(e["evidence"], dict)
    for part in ("error_before", "error_after"):
        for c in ("x_meas", "y_meas", "y_ss", "currents"):
            assert set(rep[part][c]) >= {"rms", "fit_pct"}
    assert 0.5 < rep["validation"]["fit_fraction"] < 0.9
    assert "wall" not in (written / "closeloop.json").read_text()      # no wall-clock time: byte-reproducible
    for key, p in rep["parameters"].items():                            # the format's calibrated parameters
        assert set(p) >= {"value", "se", "nominal", "relative_change", "identifiable"} and p["identifiable"] is True
    assert all(isinstance(v, str) and v for v in rep["not_identifiable"].values())
    assert set(rep["parameters"]) | set(rep["not_identifiable"]) == set(load_config()["closeloop"]["calibration"])


@pytest.mark.slow
def test_the_written_report_is_the_analysis(written, row5):
    """``closeloop.json`` holds the analysis's report as it was returned (every effect with its
    parameters, the errors before and after), its figures listed beside it."""
    from ssamb.io import jsonable

    rep = json.loads((written / "closeloop.json").read_text())
    returned = json.loads(json.dumps(row5["report"], default=jsonable))
    assert json.dumps(rep, sort_keys=True) == json.dumps(returned, sort_keys=True)     # NaN reads as NaN
    assert [e["name"] for e in rep["effects"]] and sorted(rep["figures"]) == sorted(
        p.name for p in written.iterdir() if p.suffix == ".png")


@pytest.mark.slow
def test_closeloop_figures(written):
    rep = json.loads((written / "closeloop.json").read_text())
    for name in ("calibration.png", "features.png", "residual_time.png", "residual_spectra.png", "evidence.png"):
        assert name in rep["figures"] and (written / name).stat().st_size > 10_000
    assert not [p for p in written.parent.iterdir() if p.name.startswith(".out.")]   # no temp dir left


def test_config_closeloop_section_is_valid():
    cfg = load_config()
    s = settings_from_config(cfg)
    assert isinstance(s, Settings)
    sec = cfg.get("closeloop", {})
    for name, path in sec.get("datasets", {}).items():
        assert (REPO / path).exists(), (name, path)


@pytest.mark.slow
def test_report_section_on_a_real_analysis(written):
    from ssamb.report.context import Context
    from ssamb.report.elements import Image
    from ssamb.report.sections import closeloop

    sec = closeloop(Context(Path(written), {}, {}, Path("config.yaml"), Path(written)))
    assert sec.tables() and all(len(r) == len(t.header) for t in sec.tables() for r in t.rows)
    assert all(Path(i.path).exists() for i in sec.items if isinstance(i, Image))


def test_closeloop_settings_and_schema_agree():
    """Every analysis setting has a schema entry and every schema entry a setting (or is a
    workflow key): the schema cannot drift from the code."""
    from ssamb.closeloop.estimate import EstimateSettings

    schema = yaml.safe_load((REPO / "workflow" / "schemas" / "config.schema.yaml").read_text())
    props = schema["properties"]["closeloop"]["properties"]
    fields = {f for f in Settings.__dataclass_fields__}
    from ssamb.closeloop.settings import _WORKFLOW_KEYS

    assert set(props) - set(_WORKFLOW_KEYS) == fields
    assert set(props["estimate"]["properties"]) == set(EstimateSettings.__dataclass_fields__)


def test_findings_text_one_line_each():
    from ssamb.closeloop.report import findings_text

    rep = {"summary": "s", "parameters": {"table1.mass_kg": {"value": 4.05, "se": 0.01, "nominal": 3.86,
                                                             "relative_change": 0.0492}},
           "not_identifiable": {"table1.coil_turns": "confounded with table1.mass_kg"},
           "effects": [{"name": "static_load", "params": {"fx_n": 3.0, "fy_n": -1.0}, "uncertainty": {"fx_n": 0.1},
                        "error_reduction": 0.8}],
           "error_before": {c: {"rms": 1.0} for c in ("x_meas", "y_meas", "y_ss", "currents")},
           "error_after": {c: {"rms": 0.5, "noise_rms": 0.4} for c in ("x_meas", "y_meas", "y_ss", "currents")}}
    lines = findings_text(rep)
    assert "parameter table1.mass_kg = 4.05 +- 0.01 kg (model 3.86 kg, +4.92 %)" in lines
    assert any(ln.startswith("not identifiable table1.coil_turns: confounded") for ln in lines)
    assert any(ln.startswith("effect static_load: fx_n = 3 +- 0.1, fy_n = -1") for ln in lines)


@pytest.mark.slow
def test_levitation_at_rest_closes_the_loop(tmp_path):
    """Levitation at rest (nothing excited, 0.4 s) with an 8 N load on x: the command line
    analyses it (a note says nothing excites the loop) and finds the load from the coil
    currents' slow trends (light settings)."""
    config = _light_config(tmp_path)
    sc = tmp_path / "s.yaml"
    sc.write_text(yaml.safe_dump({
        "config": str(REPO / "config.yaml"), "experiment": {"kind": "none", "seed": 3}, "duration_s": 0.4,
        "effects": [{"name": "static_load", "fx_n": 8.0, "fy_n": 0.0}],
        "noise": {"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": 5}}))
    data = tmp_path / "rig.npz"
    run_scenario(sc, data, progress=False)
    out = tmp_path / "out"
    assert main(["closeloop", str(data), "--out", str(out), "--quiet", "--config", str(config), "--workers",
                 str(REPLAY_WORKERS)]) == 0
    rep = json.loads((out / "closeloop.json").read_text())
    assert any("nothing excites the loop" in n for n in rep["notes"]), rep["notes"]
    assert [e["name"] for e in rep["effects"]] == ["static_load"], rep["summary"]
    e = rep["effects"][0]
    assert abs(e["params"]["fx_n"] - 8.0) <= max(3 * e["uncertainty"]["fx_n"], 0.8), e
    assert abs(e["params"]["fy_n"]) <= max(3 * e["uncertainty"]["fy_n"], 0.8), e
