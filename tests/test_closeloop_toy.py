"""Close the loop on a toy device: the whole engine (replay, features, calibration, signatures,
fits, joint refit, report) in seconds, on a device that is not the AMB.

The toy is a first-order plant under PI control, logged at 1 kHz: ``y`` (position, m, with sensor
noise) and ``u`` (the controller output, A). Its one calibratable parameter is the plant gain; its
one effect an input disturbance ``bias_n`` (a constant force: the integral action moves ``u`` by
``-d/b_gain`` at rest and leaves ``y`` at the reference). Data are made by the same replay with a
different seed (the rig is one more realisation of the loop's noise).
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from ssamb.device import Device, EffectModel, FeatureSpec, Record, Replay, log10_p_two_sided

FS = 1000.0


def _evidence(ft, alpha, st):
    o = ft.offsets["u"]
    lp = log10_p_two_sided(o["z"])
    return {"score": o["z"] ** 2 if lp < math.log10(alpha) else 0.0, "log10_p": lp,
            "significant": lp < math.log10(alpha), "hints": {"offset_u": o["mean"]}, "details": {"u": o}}


BIAS = SimpleNamespace(
    NAME="bias", REQUIRED=("force_n",), OPTIONAL=(), SIGNATURE="an offset of u, none of y", SEARCHABLE=True,
    NEEDS_HINT=False, validate=lambda p, where: p, evidence=_evidence,
    claim=lambda ft, hints, df, st: ft.offsets["u"]["z"] ** 2,
    model=lambda hints, rec, st: EffectModel("bias", ("force_n",), np.zeros(1), np.full(1, 0.05),
                                             np.full(1, -10.0), np.full(1, 10.0),
                                             lambda t: [{"name": "bias", "force_n": float(t[0])}], {}),
    report=lambda m, th, se, sig: [{"name": "bias", "params": {"force_n": float(th[0])},
                                    "uncertainty": {"force_n": float(se[0])}}])


class Toy(Device):
    name = "toy"
    channels = ("y", "u")
    view_names = ("y", "u")
    cost_views = ("y", "u")
    units = {"y": "m", "u": "A"}
    features = FeatureSpec(paths={"y": ("r", "y", "u")}, axis_views={"r": ("y", "u")})

    @property
    def effects(self):
        return {"bias": BIAS}

    def validate(self, arrays, source):
        pass

    def record(self, arrays, meta, cfg, source):
        n = len(arrays["y"])
        r = np.asarray(arrays["r"], float)
        return Record(self, FS, {c: np.asarray(arrays[c], float) for c in self.channels}, {"r": r},
                      {"kind": "steps"}, ("r",), {"r": r}, None, None, "levitated", None, usable=((0, n),))

    def priors(self, cfg):
        return {"plant.b_gain": 0.1}

    def floors(self, settings):
        return {"y": 1e-9, "u": 1e-9}

    def replay(self, cfg, record, effects, n, seed):
        rng = np.random.default_rng(1000 + (0 if seed is None else seed))
        a, b = cfg["plant"]["a"], cfg["plant"]["b_gain"]
        off = cfg.get("sensor", {}).get("offset_m", 0.0)
        d = sum(e["force_n"] for e in effects if e["name"] == "bias")
        r = record.inputs["r"][:n]
        y, u = np.zeros(n), np.zeros(n)
        x, integ = 0.0, 0.0
        for k in range(n):
            ym = x + off + 3e-5 * rng.standard_normal()
            e = r[k] - ym
            integ += 0.05 * e
            u[k] = 2.0 * e + integ
            y[k] = ym
            x = a * x + (1 - a) * b * (u[k] + d)
        return Replay({"y": y, "u": u})


def _data(cfg, effects, seed=99, n=8000):
    rng = np.random.default_rng(5)
    levels = rng.uniform(-1e-3, 1e-3, n // 500)
    r = np.repeat(levels, 500)[:n]
    dev = Toy()
    rec = dev.record({"y": np.zeros(n), "u": np.zeros(n), "r": r}, {}, cfg, "toy")
    ch = dev.replay(cfg, rec, effects, n, seed).channels
    return {"fs_hz": FS, "t": np.arange(n) / FS, "r": r, **ch}


CFG = {"plant": {"a": 0.95, "b_gain": 1.0},
       "closeloop": {"replay_seeds": 4, "discard_s": 0.2, "max_effects": 2, "line_search_max_hz": 400.0}}


@pytest.mark.parametrize("bias", [0.0, 0.3])
def test_the_engine_on_a_toy_device(bias):
    """The plant gain 8 % off and, in one case, a bias force: the calibration finds the gain within
    its standard errors, the effect is found when present (size within 4 standard errors) and not
    otherwise, and the held-out error drops."""
    from ssamb.closeloop import analyse

    rig = {"plant": {"a": 0.95, "b_gain": 1.08}}
    eff = [{"name": "bias", "force_n": bias}] if bias else []
    arrays = _data(rig, eff)
    rep = analyse(arrays, {}, CFG, device=Toy())
    p = rep["parameters"]["plant.b_gain"]
    assert abs(p["value"] - 1.08) < 4 * p["se"] + 0.01
    names = [e["name"] for e in rep["effects"]]
    if bias:
        assert names == ["bias"]
        f = rep["effects"][0]
        assert abs(f["params"]["force_n"] - bias) < 4 * f["uncertainty"]["force_n"] + 0.02
    else:
        assert names == []
    assert rep["error_after"]["u"]["rms"] < rep["error_before"]["u"]["rms"]
    assert set(rep["error_before"]) == {"y", "u"}


def test_combine_estimates_analytic():
    """Weighted mean, its error, the Birge ratio and the pairwise disagreement, by hand."""
    from ssamb.closeloop.recordings import combine_estimates

    d = combine_estimates([1.0, 1.3], [0.1, 0.2])
    w = np.array([100.0, 25.0])
    m = (100 * 1.0 + 25 * 1.3) / 125
    assert d["value"] == pytest.approx(m)
    chi2 = 100 * (1.0 - m) ** 2 + 25 * (1.3 - m) ** 2
    assert d["birge"] == pytest.approx(math.sqrt(chi2))
    assert d["se"] == pytest.approx(max(1.0, math.sqrt(chi2)) / math.sqrt(w.sum()))
    assert d["max_pair_z"] == pytest.approx(0.3 / math.hypot(0.1, 0.2)) and d["agree"]
    assert not combine_estimates([1.0, 2.0], [0.1, 0.1])["agree"]


def test_recordings_calibrate_on_some_and_judge_on_others():
    """Three recordings of one toy rig (gain 8 % off, a bias force): two to fit, one held out. The
    gains agree, the combined model halves the held-out error of u, and the bias survives the
    held-out test."""
    from ssamb.closeloop.recordings import analyse_recordings

    rig = {"plant": {"a": 0.95, "b_gain": 1.08}}
    eff = [{"name": "bias", "force_n": 0.3}]

    def rec(seed, shift):
        a = _data(rig, eff, seed=seed)
        a["r"] = np.roll(a["r"], shift)
        dev = Toy()
        r = dev.record({"y": a["y"], "u": a["u"], "r": a["r"]}, {}, rig, "x")
        a.update(dev.replay(rig, r, eff, len(a["r"]), seed).channels)
        return a, {}

    fit = {"a": rec(11, 0), "b": rec(12, 1700)}
    hold = {"c": rec(13, 3100)}
    out = analyse_recordings(fit, hold, CFG, device=Toy())
    assert set(out["agreement"]) == {"plant.b_gain"} and out["agreement"]["plant.b_gain"]["agree"]
    p = out["parameters"]["plant.b_gain"]
    assert abs(p["value"] - 1.08) < 4 * p["se"] + 0.01
    assert [e["name"] for e in out["effects"]] == ["bias"]
    assert out["error_before"]["u"]["above_noise"]
    assert out["error_after"]["u"]["rms"] <= 0.5 * out["error_before"]["u"]["rms"]
    assert set(out) >= {"effects", "unexplained", "error_before", "error_after", "parameters", "not_identifiable"}


def test_run_recordings_writes_the_report_and_figures(tmp_path):
    """Files in, closeloop.json and figures out; a recording named twice or no held-out one is bad input."""
    from ssamb.closeloop.recordings import run_recordings
    from ssamb.errors import InputError
    from ssamb.io import read_json

    rig = {"plant": {"a": 0.95, "b_gain": 1.08}}
    paths = []
    for k, seed in enumerate((21, 22, 23)):
        a = _data(rig, [], seed=seed, n=4000)
        p = tmp_path / f"r{k}.npz"
        np.savez(p, **a)
        paths.append(p)

    class FileToy(Toy):
        def load(self, path):
            z = np.load(path)
            return {k: z[k] for k in z.files}, {}

        def load_config(self, path=None):
            return dict(CFG)

    out = tmp_path / "out"
    rep = run_recordings(paths[:2], paths[2:], out, device=FileToy(), progress=False)
    assert (out / "closeloop.json").exists() and read_json(out / "closeloop.json")["parameters"] == rep["parameters"]
    assert {"holdout_r2.png", "holdout_spectra.png", "agreement.png"} <= set(rep["figures"])
    with pytest.raises(InputError, match="named twice"):
        run_recordings(paths[:2], paths[1:2], tmp_path / "o2", device=FileToy(), progress=False)
    with pytest.raises(InputError, match="no held-out"):
        run_recordings(paths, [], tmp_path / "o3", device=FileToy(), progress=False)
    assert not (tmp_path / "o2").exists() and not (tmp_path / "o3").exists()


def test_noise_floor_is_the_replays_spread_bounded_by_the_residual():
    """A model whose noise is the rig's: the floor is the replays' spread (times sqrt(1 + 1/m)).
    A model three times noisier than the rig above 10 % of Nyquist: the floor falls to what the
    residual shows there, not the model's own spread."""
    from scipy import signal

    from ssamb.closeloop.recordings import noise_floor

    rng = np.random.default_rng(3)
    n, m = 8192, 8
    b, a = signal.butter(2, 0.1)

    def rig_noise(hf):
        w = rng.standard_normal(n)
        lo = signal.lfilter(b, a, w)
        return lo + hf * (w - signal.lfilter(b, a, w))

    truth = np.sin(np.arange(n) / 200.0)
    runs = [truth + rig_noise(1.0) for _ in range(m)]
    meas = truth + rig_noise(1.0)
    d = noise_floor(meas, np.mean(runs, axis=0), runs)
    assert d["rms"] == pytest.approx(d["replays_rms"], rel=0.08)
    assert d["replays_rms"] == pytest.approx(np.std(rig_noise(1.0)) * math.sqrt(1 + 1 / m), rel=0.1)
    noisy = [truth + rig_noise(3.0) for _ in range(m)]
    d3 = noise_floor(meas, np.mean(noisy, axis=0), noisy)
    resid = np.sqrt(np.mean((meas - np.mean(noisy, axis=0)) ** 2))
    assert d3["replays_rms"] > 2.0 * resid
    assert d3["rms"] <= 1.05 * resid


SESSION_CFG = {**CFG, "sensor": {"offset_m": 0.0},
               "closeloop": {**CFG["closeloop"], "calibration": {"plant.b_gain": 0.1, "sensor.offset_m": 1e-3},
                             "session": ["sensor.offset_m"]}}


def _session_recordings():
    def rec(seed, off):
        return _data({"plant": {"a": 0.95, "b_gain": 1.08}, "sensor": {"offset_m": off}}, [], seed=seed), {}
    return {"a": rec(31, 3e-4), "b": rec(32, -3e-4)}, {"c": rec(33, 2e-4)}


@pytest.fixture(scope="module")
def session_run():
    from ssamb.closeloop.recordings import analyse_recordings

    fit, hold = _session_recordings()
    return analyse_recordings(fit, hold, SESSION_CFG, device=Toy())


def test_session_parameters_are_refitted_on_each_held_out_recording(session_run):
    """A sensor offset that changes between recordings (+-0.3 mm) beside a plant gain that does
    not: declared a session parameter, the offset is neither combined nor required to agree, each
    held-out recording's is calibrated on its own first part, and the gain agrees and halves the
    held-out error of u. The joint calibration of both fitting recordings finds the gain with the
    error of twice the data and each recording's own offset."""
    out = session_run
    assert "sensor.offset_m" not in out["parameters"] and "sensor.offset_m" not in out["agreement"]
    s = out["session_parameters"]["sensor.offset_m"]
    assert set(s["fit"]) == {"a", "b"} and abs(s["hold"]["c"]["value"] - 2e-4) < 5e-5
    assert out["agreement"]["plant.b_gain"]["agree"]
    assert out["error_after"]["u"]["rms"] <= 0.5 * out["error_before"]["u"]["rms"]
    # the combined model is one calibration on both fitting recordings (each with its own offset):
    # the gain within 3 standard errors, its error that of two equal recordings, 1/sqrt(2) of one's
    g = out["parameters"]["plant.b_gain"]
    assert sorted(out["joint_calibration"]["recordings"]) == ["a", "b"] and abs(g["value"] - 1.08) < 3 * g["se"]
    ratio = g["se"] / min(q["se"] for q in g["per_recording"].values())
    assert 0.6 < ratio < 0.85, ratio
    joint = s["fit_joint"]
    assert abs(joint["a"] - 3e-4) < 5e-6 and abs(joint["b"] + 3e-4) < 5e-6


def test_the_result_does_not_depend_on_the_order_or_names_of_parameters_and_recordings(session_run):
    """The same recordings and priors as above, but every config mapping's keys sorted the other
    way round (the calibration and session keys reversed), the fitting recordings listed in the
    other order and every recording renamed, and the fitting recordings analysed one by one first
    (as the workflow's jobs do): the same numbers, bit for bit (the parameters are a set,
    processed in one canonical order; the recordings in an order their data define)."""
    from ssamb.closeloop import analyse
    from ssamb.closeloop.recordings import analyse_recordings

    def reversed_deep(obj):
        return {k: reversed_deep(obj[k]) for k in sorted(obj, reverse=True)} if isinstance(obj, dict) else obj

    cfg = reversed_deep(SESSION_CFG)
    assert list(cfg["closeloop"]["calibration"]) == ["sensor.offset_m", "plant.b_gain"]
    fit, hold = _session_recordings()
    mine = {"z": fit["b"], "y": fit["a"]}
    reports = {n: analyse(a, m, cfg, device=Toy()) for n, (a, m) in mine.items()}
    out = analyse_recordings(mine, {"x": hold["c"]}, cfg, device=Toy(), reports=reports)
    ref = session_run
    rename = {"z": "b", "y": "a", "x": "c"}
    for part in ("error_before", "error_after"):
        assert out[part] == ref[part]
    assert out["parameters"]["plant.b_gain"]["value"] == ref["parameters"]["plant.b_gain"]["value"]
    assert out["parameters"]["plant.b_gain"]["se"] == ref["parameters"]["plant.b_gain"]["se"]
    jo, jr = out["joint_calibration"], ref["joint_calibration"]
    assert (jo["cost"], jo["start_costs"][jo["start"]]) == (jr["cost"], jr["start_costs"][jr["start"]])
    assert rename[jo["start"]] == jr["start"] and [rename[n] for n in jo["recordings"]] == jr["recordings"]
    s_o, s_r = out["session_parameters"]["sensor.offset_m"], ref["session_parameters"]["sensor.offset_m"]
    assert {rename[n]: v for n, v in s_o["fit_joint"].items()} == s_r["fit_joint"]
    assert s_o["hold"]["x"] == s_r["hold"]["c"]


def test_calibration_keys_are_a_set_in_the_devices_order():
    """The priors reach the estimator in one canonical order whatever order the config lists them
    in: the device's own order of its calibratable parameters, then the others sorted; the
    session keys in the same order."""
    from ssamb.closeloop.calibration import parameter_specs
    from ssamb.closeloop.settings import settings_from_config

    class OwnConfig(Toy):
        def default_config(self):
            return CFG

    cal = {"sensor.offset_m": 1e-3, "plant.b_gain": 0.1, "plant.a": 0.01}
    cfg = {**SESSION_CFG, "closeloop": {**SESSION_CFG["closeloop"], "calibration": cal,
                                        "session": ["sensor.offset_m", "plant.a"]}}
    st = settings_from_config(cfg, OwnConfig())
    assert list(st.calibration) == ["plant.b_gain", "plant.a", "sensor.offset_m"]
    assert st.session == ("plant.a", "sensor.offset_m")
    assert [s.key for s in parameter_specs(cfg, st.calibration)] == list(st.calibration)
    assert list(settings_from_config(cfg, Toy()).calibration) == sorted(cal)   # no default config: sorted
    assert list(settings_from_config(CFG, Toy()).calibration) == ["plant.b_gain"]      # the device's priors


def test_the_joint_problem_names_every_parameter():
    """The joint calibration's problem names each of its parameters, the recordings' session
    parameters included (a widened design logs the parameters by name: with the shared ones
    alone named it failed with an index error)."""
    from ssamb.closeloop.calibration import ParameterSpec
    from ssamb.closeloop.recordings import _joint_problem

    class Cmp:
        fit = SimpleNamespace(data=np.zeros(3), whitener=SimpleNamespace(residual=lambda a, b: np.zeros(3)))

        def evaluator(self, part, build):
            return lambda th, seed: np.zeros(3)

        def evaluate_many(self, part, build):
            return lambda tasks: [np.zeros(3) for _ in tasks]

        def groups(self, part):
            return [np.arange(3)]

    shared = [ParameterSpec("a.k", 1.0, True, 0.1), ParameterSpec("a.m", 2.0, True, 0.1)]
    sess = [[ParameterSpec("s.o", 0.0, False, 1e-3)], [ParameterSpec("s.o", 0.0, False, 1e-3)]]
    prob, _ = _joint_problem([Cmp(), Cmp()], shared, sess, [], names=["x", "y"])
    assert prob.names == ("a.k", "a.m", "x:s.o", "y:s.o") and len(prob.names) == len(prob.theta0)


def test_an_effect_with_which_every_joint_start_drops_the_body_is_contradicted(monkeypatch):
    """An effect found in one fitting recording with which every start of the joint calibration is
    infeasible (as if it dropped the body on another recording): the combined model is calibrated
    without it, and the effect is listed as rejected, contradicted by the fitting recordings."""
    from ssamb.closeloop import recordings

    real = recordings.joint_calibration
    calls = []

    def joint(dev, fit, reps, cfg, settings, effects, *a):
        calls.append(list(effects))
        out = real(dev, fit, reps, cfg, settings, effects, *a)
        if effects:
            out["block"]["start"] = "nominal"
        return out

    monkeypatch.setattr(recordings, "joint_calibration", joint)
    monkeypatch.setattr(recordings, "combine_effects", lambda reps: [
        {"spec": {"name": "bias", "force_n": 0.5}, "found_in": ["a"], "uncertainty": {"force_n": 0.01}}])
    fit, hold = _session_recordings()
    out = recordings.analyse_recordings(fit, hold, SESSION_CFG, device=Toy())
    assert calls == [[{"name": "bias", "force_n": 0.5}], []]
    assert out["effects"] == [] and out["joint_calibration"]["start"] != "nominal"
    (r,) = out["effects_rejected"]
    assert r["name"] == "bias" and r["holdout_z"] is None and "drops the body" in r["contradicted"]


def test_noise_read_about_the_calibrated_model():
    """Steps (no periodic excitation): the data's noise is read off the residual from a model's
    replays. Read about the nominal start (the plant gain 8 % off), the start's misfit counts as
    noise; with ``noise_at_calibration`` it is read again about the calibrated model, and the DC's
    variance is the one read about the rig's own model."""
    from ssamb.closeloop import _analyse

    arrays = _data({"plant": {"a": 0.95, "b_gain": 1.08}}, [])
    var = {}
    for flag in (False, True):
        cfg = {**CFG, "closeloop": {**CFG["closeloop"], "noise_at_calibration": flag}}
        rep, art = _analyse(arrays, {}, cfg, device=Toy())
        cmp = art["comparison"]
        var[flag] = np.diag(cmp.fit.data.cov_dc).copy()
        assert abs(rep["parameters"]["plant.b_gain"]["value"] - 1.08) < 0.01
    cmp.calibrate_noise({"plant.b_gain": 1.08})
    truth = np.diag(cmp.fit.data.cov_dc)
    np.testing.assert_allclose(var[True], truth, rtol=0.01)
    assert var[False][0] > 1.3 * truth[0]
