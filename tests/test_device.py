"""The device interface: what close the loop may import, and what every device and effect module
provides."""
from __future__ import annotations

import ast
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from ssamb.device import DEVICES, Device, EffectModel, get_device
from ssamb.errors import InputError

ROOT = Path(__file__).resolve().parent.parent
#: device packages close the loop must not import (only through ssamb.device)
DEVICE_PACKAGES = ("ssamb.sim", "ssamb.maglev1d")


def _imports(path: Path) -> set:
    """Absolute names of the ssamb modules a file imports."""
    tree = ast.parse(path.read_text())
    pkg = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = pkg.split(".")
            if node.level:
                base = base[: len(base) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.add(name)
            out.update(f"{name}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_close_the_loop_knows_devices_only_through_the_interface():
    """No module of ssamb/closeloop imports a device package; none of a device imports close the loop."""
    for f in sorted((ROOT / "ssamb" / "closeloop").glob("*.py")):
        bad = [m for m in _imports(f) if m.startswith(DEVICE_PACKAGES)]
        assert not bad, f"{f.name} imports {bad}"
    for pkg in DEVICE_PACKAGES:
        folder = ROOT.joinpath(*pkg.split("."))
        for f in sorted(folder.rglob("*.py")) if folder.exists() else []:
            bad = [m for m in _imports(f) if m.startswith(("ssamb.closeloop", "ssamb.report", "ssamb.stages"))]
            assert not bad, f"{f.relative_to(ROOT)} imports {bad}"


def test_unknown_device_is_named():
    with pytest.raises(InputError, match="device 'nope': unknown .*amb"):
        get_device("nope")


AMB_LIBRARY = ("sensor_delay", "unbalance", "static_load", "sensor_gain", "amplifier_deadtime", "cross_coupling")


def test_the_amb_device_library_and_views():
    d = get_device("amb")
    assert isinstance(d, Device) and d.name == "amb"
    assert d.library == AMB_LIBRARY
    assert set(d.effects) == set(AMB_LIBRARY) | {"external_force"}
    ch = {c: np.full(4, float(i)) for i, c in enumerate(d.channels)}
    v = d.views(ch)
    assert set(v) == set(d.view_names) and set(d.cost_views) <= set(v)
    assert np.all(v["d_x"] == 0.5 * (ch["i_xpos"] - ch["i_xneg"]))
    assert all(d.unit(x) in ("m", "A") for x in d.view_names + d.channels)
    from ssamb.closeloop.settings import Settings

    fl = d.floors(Settings())
    assert set(d.view_names + d.channels) <= set(fl) and fl["x_meas"] == Settings().floor_position_m


@pytest.mark.parametrize("name", list(DEVICES))
def test_every_effect_module_has_the_interface(name):
    try:
        d = get_device(name)
    except ImportError:
        pytest.skip(f"device {name} not available")
    for n, m in d.effects.items():
        assert m.NAME == n
        for attr in ("REQUIRED", "OPTIONAL", "SIGNATURE", "SEARCHABLE", "NEEDS_HINT"):
            assert hasattr(m, attr), f"{n}.{attr}"
        for fn in ("validate", "evidence", "claim", "model", "report"):
            assert callable(getattr(m, fn, None)), f"{n}.{fn}"


def test_amb_sensor_gain_on_y_is_the_dcm_calibration():
    """With the DCM calibration gain calibrated, a sensor gain is fitted on x only, excited or not
    (an unexcited axis still closes its loop through its sensor); without it on both axes."""
    d = get_device("amb")
    st = SimpleNamespace(calibration={"selfsensing.calibration_gain_error": 0.03})
    m = d.effect_model("sensor_gain", {"axes": ["x", "y"], "gain_x": 1.1}, SimpleNamespace(excited_axes=("x", "y")), st)
    assert isinstance(m, EffectModel) and m.fixed["axes"] == ("x",)
    assert m.theta0[0] == pytest.approx(0.1)
    m1 = d.effect_model("sensor_gain", {}, SimpleNamespace(excited_axes=("y",)), st)
    assert m1.fixed["axes"] == ("x",)
    m2 = d.effect_model("sensor_gain", {}, SimpleNamespace(excited_axes=("y",)), SimpleNamespace(calibration={}))
    assert m2.fixed["axes"] == ("x", "y")


def test_amb_effect_report_entries_merge_agreeing_axes():
    d = get_device("amb")
    m = d.effect_model("sensor_delay", {"axes": ["x", "y"]}, SimpleNamespace(excited_axes=("x", "y"), fs_hz=83300.0),
                       None)
    ent = d.report_entries(m, [30e-6, 30.5e-6], [1e-6, 1e-6], [True, True])
    assert len(ent) == 1 and ent[0]["params"]["axis"] == "both"
    w = 1 / 1e-12
    assert ent[0]["params"]["delay_s"] == pytest.approx((30e-6 + 30.5e-6) / 2)
    assert ent[0]["uncertainty"]["delay_s"] == pytest.approx(1 / math.sqrt(2 * w))
    ent = d.report_entries(m, [30e-6, 60e-6], [1e-6, 1e-6], [True, True])
    assert [e["params"]["axis"] for e in ent] == ["x", "y"]


def test_sensor_delay_starts_in_every_sample_interval():
    """The delay's coarse starts: an axis without a hint at four points of every controller sample
    interval up to 120 us (the interpolated delay's cost has a kink at every
    whole sample); an axis with a hint only in its interval and the two beside it."""
    d = get_device("amb")
    ts = 1 / 83300.0
    rec = SimpleNamespace(excited_axes=("y",), fs_hz=83300.0)
    m = d.effect_model("sensor_delay", {"axes": ["x"], "delay_x": 30e-6}, rec, None)
    y = sorted({round(g[1] / ts, 6) for g in m.grid if g[0] == m.theta0[0]})
    assert y == [0.0] + [k + f for k in range(10) for f in (0.125, 0.375, 0.625, 0.875)]
    x = sorted({round(g[0] / ts, 6) for g in m.grid if g[1] == m.theta0[1]} - {round(30e-6 / ts, 6)})
    assert x == [k + f for k in (1, 2, 3) for f in (0.125, 0.375, 0.625, 0.875)]


def test_validate_effect_through_the_device():
    d = get_device("amb")
    assert d.validate_effect({"name": "static_load", "fx_n": 1.0, "fy_n": 0.0}) == \
        {"name": "static_load", "fx_n": 1.0, "fy_n": 0.0}
    with pytest.raises(InputError, match="missing parameter 'fy_n'"):
        d.validate_effect({"name": "static_load", "fx_n": 1.0})
    with pytest.raises(InputError, match="'gravity_wave': unknown"):
        d.validate_effect({"name": "gravity_wave"})


def test_an_effect_is_a_module_of_the_device_package(tmp_path, monkeypatch):
    """A module dropped into a device's effect package is in its library, in ``ORDER`` then by
    name; a module whose name starts with an underscore is a helper, not an effect."""
    from ssamb.device import effect_modules

    pkg = tmp_path / "toyfx"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "_shared.py").write_text("X = 1\n")
    for name, order in (("zeta", 1), ("alpha", 2), ("beta", None)):
        (pkg / f"{name}.py").write_text(f"NAME = '{name}'\n" + (f"ORDER = {order}\n" if order else ""))
    monkeypatch.syspath_prepend(str(tmp_path))
    assert [m.NAME for m in effect_modules("toyfx")] == ["zeta", "alpha", "beta"]


def test_reasons_quote_absolute_parameters_in_their_unit():
    """A parameter whose nominal value is 0 (an offset in m) has its uncertainties quoted in its
    own unit, a relative one in per cent of the nominal value."""
    from ssamb.closeloop.calibration import identifiability

    info = np.diag([1.0 / 7.1e-4 ** 2, 1.0 / 0.5 ** 2])
    out = identifiability(info, np.array([2e-4, 0.2]), ("sensors.offset_m", "mass_kg"), 1 / 3,
                          relative=(False, True))["per_parameter"]
    assert "0.00071" in out["sensors.offset_m"]["reason"] and "%" not in out["sensors.offset_m"]["reason"]
    assert "50 %" in out["mass_kg"]["reason"]


def test_a_replay_never_repeats_the_noise_of_a_rig_simulated_with_its_seed(tmp_path):
    """A simulated rig (seed 4, the model's own parameters, no logging noise) and the AMB's
    replays of its record with seeds 4 and 5: the replay with the rig's seed is as far from the
    rig's x channel as the one with another seed (its converter noise is its own stream,
    :data:`ssamb.device.REPLAY_STREAM`), not a copy of it; and a replay is reproducible."""
    import yaml

    from ssamb.config import load_config
    from ssamb.rig import load_scenario, rig_data

    cfg = load_config()
    sc = {"config": str(Path(__file__).resolve().parent.parent / "config.yaml"), "duration_s": 0.1,
          "experiment": {"kind": "multisine", "point": "position", "axis": "x", "amplitude_m": 2e-5, "f_min_hz": 50,
                         "f_max_hz": 100, "f_resolution_hz": 50, "periods": 5, "seed": 4}}
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(sc))
    arrays, meta = rig_data(load_scenario(tmp_path / "rig.yaml"))
    dev = get_device("amb")
    rec = dev.record(arrays, meta, cfg, "rig")
    n = len(arrays["t"])
    rms = {s: float(np.sqrt(np.mean((dev.replay(cfg, rec, [], n, s).channels["x_meas"] - arrays["x_meas"]) ** 2)))
           for s in (4, 5)}
    assert rms[4] > 0.5 * rms[5] > 0, rms
    again = dev.replay(cfg, rec, [], n, 4).channels["x_meas"]
    np.testing.assert_array_equal(again, dev.replay(cfg, rec, [], n, 4).channels["x_meas"])


def _at_rest(cfg: dict, effects: list) -> dict:
    """0.3 s of the AMB levitated at rest (the same seed for every model: the same noise), its
    logged channels."""
    from ssamb.sim import simulate

    res = simulate(cfg, duration_s=0.3, excitation={"kind": "none"}, start="levitated", effects=effects,
                   seed=7, progress=False)
    return {c: np.asarray(res.data[c], float) for c in ("x_meas", "y_meas", "y_ss", "i_xpos", "i_xneg", "i_ypos",
                                                        "i_yneg", "u_x", "u_y", "fs_hz")}


def _mean_se(x: np.ndarray, k: int = 10) -> tuple[float, float]:
    """Mean and its standard error from ``k`` batch means (the loop's noise is coloured)."""
    b = x[: len(x) // k * k].reshape(k, -1).mean(axis=1)
    return float(b.mean()), float(b.std(ddof=1) / math.sqrt(k))


def test_at_rest_a_cross_coupling_has_the_means_of_a_static_load_and_its_own_noise_spectrum():
    """The AMB's ``ALIASES`` claim, by simulation: at rest a cross coupling of 0.1 moves every
    channel's mean as the static load :math:`(F_x, F_y)` that gives the same mean differential
    currents does (the load found by linearity from two 5 N loads): all nine channels' means
    within 3 standard errors of each other, while the coupling moves the x currents' mean by
    hundreds. What the means do not show: the y loop's noise, coupled into x, raises the x
    probe's noise spectrum at 40-500 Hz several times over the load's -- the AMB's features do
    not compare noise spectra (its ``band_views`` are empty), so on them the two are aliases."""
    from scipy import signal

    from ssamb.config import load_config

    cfg = load_config()
    cc = _at_rest(cfg, [{"name": "cross_coupling", "coefficient": 0.1}])
    none = _at_rest(cfg, [])
    d = {ax: (lambda ch, ax=ax: np.mean(ch[f"i_{ax}pos"] - ch[f"i_{ax}neg"])) for ax in "xy"}
    f_n = {}
    for ax in "xy":
        unit = _at_rest(cfg, [{"name": "static_load", "fx_n": 5.0 * (ax == "x"), "fy_n": 5.0 * (ax == "y")}])
        f_n[ax] = 5.0 * (d[ax](cc) - d[ax](none)) / (d[ax](unit) - d[ax](none))
    load = _at_rest(cfg, [{"name": "static_load", "fx_n": f_n["x"], "fy_n": f_n["y"]}])
    fs_hz = float(cc.pop("fs_hz"))
    for c in cc:
        (m1, s1), (m2, s2) = _mean_se(cc[c]), _mean_se(load[c])
        assert abs(m1 - m2) < 3 * math.hypot(s1, s2), (c, m1, m2, s1, s2)
    (m1, s1), (m0, s0) = _mean_se(cc["i_xpos"]), _mean_se(none["i_xpos"])
    assert abs(m1 - m0) > 100 * math.hypot(s1, s0)
    f, p_cc = signal.welch(cc["x_meas"], fs_hz, nperseg=4096)
    _, p_load = signal.welch(load["x_meas"], fs_hz, nperseg=4096)
    band = (f >= 40.0) & (f <= 500.0)
    assert p_cc[band].mean() > 3.0 * p_load[band].mean()
