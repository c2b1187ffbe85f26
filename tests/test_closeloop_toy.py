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
    model=lambda hints, rec, st: EffectModel("bias", ("force_n",), np.zeros(1), np.full(1, 0.05), np.full(1, -10.0),
                                             np.full(1, 10.0), lambda t: [{"name": "bias", "force_n": float(t[0])}], {}),
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
        d = sum(e["force_n"] for e in effects if e["name"] == "bias")
        r = record.inputs["r"][:n]
        y, u = np.zeros(n), np.zeros(n)
        x, integ = 0.0, 0.0
        for k in range(n):
            ym = x + 3e-5 * rng.standard_normal()
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
