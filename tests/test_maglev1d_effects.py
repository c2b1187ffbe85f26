"""The levitated ball's effect library: each module's interface, its evidence on hand-made
features, and the signature it claims, checked on replays."""
import copy
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from ssamb.device import EffectModel, effect_modules, get_device
from ssamb.maglev1d.physics import neutral_knobs

ROOT = Path(__file__).resolve().parent.parent
MODULES = effect_modules("ssamb.maglev1d.effects")
DEV = get_device("maglev1d")
CFG = DEV.default_config()
SETTINGS = SimpleNamespace(calibration={})
ALPHA = 1e-3

#: a size of each effect that a replay resolves
SIZES = {"sensor_delay": {"delay_s": 3e-3}, "actuation_delay": {"delay_s": 2e-3}, "sensor_gain": {"gain": 0.9},
         "sensor_offset": {"offset_m": 2e-4}, "static_load": {"fy_n": 0.02}, "eddy_current": {"tau_s": 2e-3},
         "saturation": {"coefficient_per_a2": 0.5}, "amplifier_drop": {"drop_v": 0.5},
         "current_offset": {"offset_a": 0.02}, "resistance_drift": {"rate_ohm_per_s": 0.02},
         "remanence": {"mmf_a": 0.02}, "sensor_nonlinearity": {"curvature_per_m": 25.0}}


def _features(offsets=None, ratios=None, windows=None):
    off = {v: {"mean": 0.0, "se": 1.0, "z": 0.0} for v in ("y", "i", "u")}
    for v, (mean, z) in (offsets or {}).items():
        off[v] = {"mean": mean, "se": abs(mean / z) if z else 1.0, "z": z}
    rat = {}
    for p, (kind, z, val) in (ratios or {}).items():
        r = {"alpha": 0.0, "se_alpha": 0.01, "z_alpha": 0.0, "gain": 1.0, "tau_s": 0.0, "se_tau_s": 1e-4,
             "z_tau": 0.0, "chi2_alpha": 0.0, "chi2_tau": 0.0, "n_lines": 20, "axis": "y", "path": p}
        if kind == "tau":
            r.update(tau_s=val, z_tau=z, chi2_tau=z * z)
        else:
            r.update(alpha=np.log(val), gain=val, z_alpha=z, chi2_alpha=z * z)
        rat[p] = r
    return SimpleNamespace(offsets=off, ratios=rat, windows=windows or {})


def _window(slope, n=20, se=0.01):
    t = np.arange(n) * 1.0
    return {"t_s": t, "mean": slope * t, "se": np.full(n, se), "chi2": 0.0, "k": n}


#: hand-made features showing each effect's signature
SIGNS = {
    "sensor_delay": _features(ratios={"y/i": ("tau", 8.0, 3e-3)}),
    "actuation_delay": _features(ratios={"i/u": ("tau", 8.0, 2e-3)}),
    "sensor_gain": _features(ratios={"y/i": ("alpha", -8.0, 0.9)}),
    "eddy_current": _features(ratios={"y/i": ("tau", 8.0, 2e-3), "i/u": ("tau", -6.0, -1e-3)}),
    "static_load": _features(offsets={"i": (0.02, 9.0), "u": (0.2, 7.0)}),
    "amplifier_drop": _features(offsets={"u": (0.5, 9.0)}),
    "current_offset": _features(offsets={"i": (0.02, 9.0)}),
    "remanence": _features(offsets={"i": (-0.02, -9.0), "u": (-0.2, -7.0)}),
    "resistance_drift": _features(windows={"u": _window(0.01), "i": _window(0.0)}),
}
#: effects that share a signature (told apart by the fit, not the evidence)
SAME = {"static_load": {"sensor_offset", "saturation"}, "remanence": {"static_load", "sensor_offset"}}


@pytest.mark.parametrize("mod", MODULES, ids=lambda m: m.NAME)
def test_module_interface(mod):
    assert isinstance(mod.NAME, str) and mod.SIGNATURE and mod.REQUIRED
    assert isinstance(mod.SEARCHABLE, bool) and isinstance(mod.NEEDS_HINT, bool)
    e = DEV.validate_effect({"name": mod.NAME, **SIZES[mod.NAME]})
    kn = neutral_knobs()
    mod.apply(kn, e, CFG)
    assert kn != neutral_knobs()                    # it enters the replay
    rec = _record()
    m = mod.model({}, rec, SETTINGS)
    assert isinstance(m, EffectModel) and len(m.params) == len(m.theta0)
    assert np.all(m.lower <= m.theta0) and np.all(m.theta0 <= m.upper)
    for spec in m.build(m.theta0 + m.step):
        DEV.validate_effect(spec)
    rep = mod.report(m, m.theta0, m.step, np.ones(len(m.params), bool))
    assert rep[0]["name"] == mod.NAME and set(rep[0]["params"]) == set(rep[0]["uncertainty"])


def test_bad_effect_parameters_named():
    from ssamb.errors import InputError

    with pytest.raises(InputError, match="'sensor_delay'.*delay_s"):
        DEV.validate_effect({"name": "sensor_delay", "delay_s": 0.02})
    with pytest.raises(InputError, match="'static_load'.*fy_n.*finite"):
        DEV.validate_effect({"name": "static_load", "fy_n": float("nan")})
    with pytest.raises(InputError, match="unknown effect"):
        DEV.validate_effect({"name": "unbalance", "speed_hz": 10})


@pytest.mark.parametrize("name", sorted(SIGNS))
def test_evidence_on_its_own_signature_only(name):
    lib = DEV.effects
    quiet = _features()
    for other, mod in lib.items():
        ev = mod.evidence(SIGNS[name], ALPHA, SETTINGS)
        expect = other == name or other in SAME.get(name, set())
        assert ev["significant"] == expect, (name, other, ev)
        assert set(ev) >= {"score", "log10_p", "significant", "hints", "details"}
        assert not mod.evidence(quiet, ALPHA, SETTINGS)["significant"]


def test_hints_give_the_size():
    lib = DEV.effects
    assert lib["sensor_delay"].evidence(SIGNS["sensor_delay"], ALPHA, SETTINGS)["hints"]["delay_s"] == 3e-3
    rec = _record()
    m = lib["sensor_gain"].model(lib["sensor_gain"].evidence(SIGNS["sensor_gain"], ALPHA, SETTINGS)["hints"],
                                 rec, SETTINGS)
    assert m.theta0[0] == pytest.approx(-0.1)
    m = lib["amplifier_drop"].model({"offset_u_v": 1.0}, rec, SETTINGS)
    assert m.theta0[0] == pytest.approx(CFG["amplifier"]["v_max_v"] / CFG["controller"]["v_ref_v"])


def test_calibrated_sensor_and_stage_leave_their_effects_a_reason():
    """With the device's priors calibrated, the effects the calibration absorbs give a reason
    (test_effects_the_calibration_absorbs checks the physics); across levels saturation and the
    sensor's curvature are fitted, at one level they give a reason too."""
    st = SimpleNamespace(calibration=DEV.priors(CFG))
    rec = _record()
    for name in ("sensor_gain", "sensor_offset", "amplifier_drop", "current_offset", "remanence", "static_load"):
        assert isinstance(DEV.effects[name].model({}, rec, st), str), name
    for name in ("saturation", "sensor_nonlinearity", "eddy_current", "sensor_delay", "actuation_delay",
                 "resistance_drift"):
        assert not isinstance(DEV.effects[name].model({}, rec, st), str), name
    one = _record("constante")
    for name in ("saturation", "sensor_nonlinearity"):
        assert "one level" in DEV.effects[name].model({}, one, st), name


_REC = {}


def _record(name="escalon"):
    """A shipped recording's record; ``_REC["cfg"]``: the escalon log's start estimate (a model
    near the rig)."""
    for n in {name, "escalon"} - set(_REC):
        p = sorted((ROOT / "resources" / "maglev1d").glob(f"dataset_{n}_*.npz"))[0]
        arrays, meta = DEV.load(p)
        _REC[n] = DEV.record(arrays, meta, CFG, str(p))
    if "cfg" not in _REC:
        cfg = copy.deepcopy(CFG)
        for k, v in DEV.initial_estimate(_REC["escalon"], CFG).items():
            sec, key = k.split(".")
            cfg[sec][key] = v
        _REC["cfg"] = cfg
    return _REC[name]


def _means(effects, n=990):
    """Means over the first level of the escalon log (5 mm, before its step at 10 s)."""
    rec = _record()
    rep = DEV.replay(_REC["cfg"], rec, effects, n, None)
    a, _ = rec.usable[0]
    return {c: float(np.mean(rep.channels[c][a:n])) for c in DEV.channels}, rep


@pytest.mark.parametrize("name, shifted, clean", [
    ("amplifier_drop", ("u",), ("i", "y")),
    ("current_offset", ("i",), ("u", "y")),
    ("static_load", ("i", "u"), ("y",)),
    ("sensor_offset", ("i", "u"), ("y",)),
    ("remanence", ("i", "u"), ("y",)),
])
def test_offset_signatures_hold_in_replays(name, shifted, clean):
    """The loop's integral actions put a force-like effect into i and u, the stage's drop into u
    alone, the current reading's offset into i alone; the position is held (noise-free replays
    of the escalon log's first level from the data's start estimate)."""
    base, _ = _means([])
    eff, rep = _means([{"name": name, **SIZES[name]}])
    assert not rep.contact
    q = {"y": 0.05 / 1023, "i": 5 / 2.2 / 1023, "u": 9.86 / 254}
    for v in shifted:
        assert abs(eff[v] - base[v]) > 3 * q[v], (v, eff[v] - base[v])
    for v in clean:
        assert abs(eff[v] - base[v]) < max(0.2 * abs(eff[shifted[0]] - base[shifted[0]]) * q[v] / q[shifted[0]],
                                           q[v]), v


def test_zero_size_effects_are_neutral():
    rec = _record()
    a = DEV.replay(_REC["cfg"], rec, [], rec.n, 3)
    assert DEV.replay(_REC["cfg"], rec, [], 990, 3).channels["y"].shape == (990,)
    zero = [{"name": "sensor_delay", "delay_s": 0.0}, {"name": "static_load", "fy_n": 0.0},
            {"name": "eddy_current", "tau_s": 0.0}, {"name": "sensor_gain", "gain": 1.0}]
    b = DEV.replay(_REC["cfg"], rec, zero, rec.n, 3)
    for c in DEV.channels:
        np.testing.assert_array_equal(a.channels[c], b.channels[c])


def _smooth(cfg, rec, effects):
    """A noise-free replay of the record's compared parts without ADC or PWM rounding (smooth in
    every parameter), as the rows y, i, u."""
    from ssamb.maglev1d import controller as C
    from ssamb.maglev1d import physics as P

    kn = DEV.knobs(cfg, effects)
    p = P.knobs_of(cfg, kn)
    for k, v in (("position_lsb_m", 1e-9), ("position_counts", 1e9), ("current_lsb_a", 1e-9),
                 ("current_counts", 1e9), ("pwm_steps", 0.0)):
        p[P.knob_index(k)] = v
    segs = list(rec.usable)
    out = P.simulate(p, C.gains_of(cfg), rec.inputs["yd"], segs, DEV.initial_states(rec, cfg, kn, segs), None)
    idx = np.concatenate([np.arange(a, b) for a, b in segs])
    return np.stack([out[c][idx] for c in ("y", "i", "u")])


def _recalibrated_misfit(name, size, recording):
    """Per-sample rms (in units of the rig's noise per channel) between a replay with the effect and
    the best replay without it, all six calibrated parameters refitted."""
    from scipy.optimize import least_squares

    from ssamb.config import apply_overrides, get

    rec = _record(recording)
    cfg = _REC["cfg"]
    target = _smooth(cfg, rec, [{"name": name, **size}])
    noise = np.array([[CFG["noise"]["position_m"] + 0.05 / 1023 / 12 ** 0.5], [CFG["noise"]["current_a"]], [0.3]])
    keys = list(DEV.priors(CFG))
    x0 = np.array([float(get(cfg, k)) for k in keys])
    sc = np.where(np.abs(x0) > 0, np.abs(x0), 1e-3)

    def f(z):
        return ((_smooth(apply_overrides(cfg, dict(zip(keys, z * sc))), rec, []) - target) / noise).ravel()

    before = np.sqrt(np.mean(f(x0 / sc).reshape(3, -1) ** 2, axis=1))
    sol = least_squares(f, x0 / sc, diff_step=1e-5, x_scale="jac", max_nfev=40)
    return before, np.sqrt(np.mean(sol.fun.reshape(3, -1) ** 2, axis=1)), sol.fun.size // 3


@pytest.mark.slow
@pytest.mark.parametrize("name, size, recording, absorbed", [
    ("current_offset", {"offset_a": 0.02}, "escalon", True),
    ("remanence", {"mmf_a": 0.015}, "escalon", True),
    ("static_load", {"fy_n": 0.012}, "escalon", True),
    ("saturation", {"coefficient_per_a2": 0.6}, "constante", True),
    ("saturation", {"coefficient_per_a2": 0.6}, "escalon", False),
    ("eddy_current", {"tau_s": 0.004}, "escalon", False),
])
def test_effects_the_calibration_absorbs(name, size, recording, absorbed):
    """What the effect modules' identifiability says: with the six nominal parameters refitted,
    a model without the effect reproduces a noise-free replay with it within the noise (no
    chi-square excess of 3 standard deviations over the record: n r^2 < 3 sqrt(2 n) per channel)
    -- or, for the effects the data do identify, it does not."""
    before, after, n = _recalibrated_misfit(name, size, recording)
    assert np.max(before) > 1.0                         # the effect itself stands above the noise
    detectable = n * after ** 2 > 3 * np.sqrt(2 * n)
    assert (not detectable.any()) == absorbed, (before, after)
