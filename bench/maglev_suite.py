"""Close the loop on simulated levitation rigs: the randomized suite of the maglev1d device.

    python bench/maglev_suite.py [--draws 24] [--null 20] [--seed 20261126] [--processes 2]
                                 [--center results/rigs/maglev1d/closeloop.json] [--out suite.jsonl]

Each draw takes a real recording (drawn among the five) and builds a rig that is not the model,
conditioned on what the recording says of the real rig (the device config's ``suite`` section):
every calibratable parameter is drawn uniformly within one prior standard deviation of the rig's
centre (the values the device's physical checks imply on the step recording, replaced by the
parameters the real recordings identified, from ``--center``), then the force constant and the
stage's full-scale voltage put the rig, with its effect, in the force and command balance the
recording shows at the starts of its usable parts (:meth:`ssamb.maglev1d.device.Maglev1D.balanced`:
the replay starts there from the recording's state, and a rig off that balance meets a stop within
0.1 s). A rig is drawn again (with its effect's size) when that balance lies beyond the prior,
when it is no physical rig, when its linearised loop is unstable at a level the reference visits,
when its replay touches a stop or never levitates, when its data levitate on other stretches than
the recording's ball or its own model, replayed on the draw's record, drops the ball
(:func:`_alike`), or when its data do not show its effect (:func:`effect_shows`: the engine's own
held-out test of the rig with the effect over the same rig without it); the reasons are counted
(``refused``) and printed with the draw. A rig is drawn again until one passes, up to
``--attempts`` rigs (:data:`ATTEMPTS`): the rig is drawn from the prior *conditioned* on what the
recording shows of the real rig (it levitated that experiment), a condition decided from the rig
and its own data before any analysis, so a redraw never looks at the engine's result. A cap reached
leaves the draw without data, reported as such; with a small cap, draws whose recording and effect
levitate rarely (an actuation delay or an eddy current on multiescalon's steps near the magnet,
where the loop has the least margin) were dropped as a group, not at random. The rig gets one
library effect with a size drawn from its range (:data:`SIZES`), among the effects the device can
identify on that recording, or none in the null draws. The rig's data are a replay of that rig
driven by the recording's reference, each levitated stretch from
the recording's state at its start but with the controller's state that the rig's own log gives there
(:meth:`Maglev1D.rig_log`), with a seed of its own and its converters rounding as a rig's do; the analysis
(:func:`ssamb.closeloop.analyse`) sees only the data and the published-parameter model.
``--unbalanced --any-size`` draws the rigs as before these conditions (same draws).

A draw with an effect passes when the effect is found (first in the list of effects) and its
size is within three standard errors or 25 % of the truth; a null draw passes when no effect is
declared. A draw whose truth is named among the rivals of the effect found first (effects the data
cannot tell apart, :func:`ssamb.closeloop.search.champion`) fails, and is counted apart. Effects
the device says a recording cannot identify (their parameterisation returns a reason: absorbed by
the calibrated parameters, or visible only across levels) are not drawn there and are listed with
the reason. One JSON line per draw goes to ``--out`` as it ends; the
summary printed at the end: pass rates, per effect, false alarms, time per draw.

Every draw is also set against its truth (:func:`against_truth`): the rig's own model (its
parameters and its effect) and the analysis's final model each predict the draw's data (mean of
``REPLAYS`` seeded replays) on the fitting and on the held-out part. A draw whose truth does not
predict the held-out data significantly better than the final model (one-sided paired t-test
over 0.2 s blocks of the summed squared residuals, each channel scaled by the truth's residual
variance, level ``ALPHA``) is *invisible*: these data cannot show its effect, and it is counted
apart, never as a find nor hidden. The oracle check tells a miss of the search from a limit of
the data: the truth significantly better on the fitting part, which the search minimised, means
the search stopped short of a better model it could have reached. The engine's own held-out test
of the truth over the final model (:func:`held_out_z`) is read in the noise-only draws too: where
it is significant there, the calibration alone ends short of the rig's truth.
"""
from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import sys
import time
from collections import Counter
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
RECORDINGS = sorted((REPO / "resources" / "maglev1d").glob("dataset_*.npz"))
#: effect -> (parameter, lower, upper, signed): the size of a drawn effect, uniform in [lower, upper]
#: (either sign when signed); a detectable but realistic size for a 100 Hz log of a levitated ball
SIZES = {
    "sensor_delay": ("delay_s", 2e-3, 8e-3, False),
    "actuation_delay": ("delay_s", 2e-3, 8e-3, False),
    "sensor_gain": ("gain", 0.06, 0.15, True),
    "sensor_offset": ("offset_m", 3e-4, 1e-3, True),
    "static_load": ("fy_n", 0.02, 0.05, True),
    "eddy_current": ("tau_s", 3e-3, 1e-2, False),
    "saturation": ("coefficient_per_a2", 0.3, 1.0, False),
    "amplifier_drop": ("drop_v", 0.5, 1.5, False),
    "current_offset": ("offset_a", 0.01, 0.03, True),
    "resistance_drift": ("rate_ohm_per_s", 0.005, 0.02, False),
    "remanence": ("mmf_a", 0.01, 0.03, True),
    "sensor_nonlinearity": ("curvature_per_m", 10.0, 28.0, True),
}


#: the rigs drawn for one draw at most before it is left without data (module docstring): far
#: above the redraws the rarest pairs of recording and effect need (docs/validation.md)
ATTEMPTS = 1000

#: replays averaged into a prediction, the level of the truth-against-final-model test, and its
#: blocks (s): several periods of the loop's 2-7 Hz modes, at least 5 in a held-out part of 1 s
REPLAYS, ALPHA, BLOCK_S = 8, 0.01, 0.2


def _prediction(dev, cfg, rec, effects, seeds) -> dict:
    outs = [dev.replay(cfg, rec, effects, rec.n, s) for s in seeds]
    return {**{c: np.mean([o.channels[c] for o in outs], axis=0) for c in dev.channels},
            "contacts": sum(bool(o.contact) for o in outs)}


def _better(channels, data, p_a, p_b, a: int, b: int, fs_hz: float) -> tuple[float, float]:
    """``p_b``'s cost over ``p_a``'s on samples ``a:b`` of ``data`` (each channel scaled by
    ``p_a``'s residual variance) and the one-sided p-value of '``p_a`` predicts better'
    (paired t-test over ``BLOCK_S`` blocks; 1 with fewer than 5 blocks)."""
    from scipy import stats

    d, cost_a, cost_b = 0.0, 0.0, 0.0
    for c in channels:
        ra = data[c][a:b] - p_a[c][a:b]
        rb = data[c][a:b] - p_b[c][a:b]
        v = max(float(np.var(ra)), 1e-30)
        d = d + (rb ** 2 - ra ** 2) / v
        cost_a += float(np.mean(ra ** 2)) / v
        cost_b += float(np.mean(rb ** 2)) / v
    w = int(round(BLOCK_S * fs_hz))
    blocks = np.array([np.mean(d[k:k + w]) for k in range(0, len(d) - w + 1, w)])
    if len(blocks) >= 5 and np.std(blocks) > 0:
        tt = np.mean(blocks) / (np.std(blocks, ddof=1) / np.sqrt(len(blocks)))
        pv = float(stats.t.sf(tt, len(blocks) - 1))
    else:
        pv = 1.0
    return cost_b / max(cost_a, 1e-30), pv


def against_truth(dev, cfg, rig, true, data, meta, rep, seed: int, ov: dict | None = None) -> dict:
    """The truth (``rig`` with the effect ``true``) and the analysis's final model against the
    draw's data on its fitting and held-out parts (module docstring): per part the ratio of the
    final model's cost to the truth's (1: as good) and the one-sided p-value of 'the truth
    predicts better'."""
    from ssamb.config import apply_overrides

    rec = dev.record(data, meta, cfg, "draw")
    fin = rep.get("final_model", {})
    seeds = [seed * 1000 + j for j in range(REPLAYS)]
    p_true = _prediction(dev, rig, rec, [true] if true else [], seeds)
    p_fin = _prediction(dev, apply_overrides(cfg, fin.get("overrides", {})), rec, fin.get("effects", []), seeds)
    out = {}
    val = rep["validation"]
    for part, (t0, t1) in (("fit", val["fit_s"]), ("holdout", val["holdout_s"])):
        a, b = int(round(t0 * rec.fs_hz)), int(round(t1 * rec.fs_hz))
        ratio, pv = _better(dev.channels, data, p_true, p_fin, a, b, rec.fs_hz)
        out[part] = {"cost_ratio": ratio, "p_truth_better": pv}
    out["contacts"] = {"truth": p_true["contacts"], "final": p_fin["contacts"], "of": REPLAYS}
    out["visible"] = out["holdout"]["p_truth_better"] < ALPHA
    out["search_short"] = out["fit"]["p_truth_better"] < ALPHA
    if ov is not None:                   # the engine's own held-out test of the truth over the final model
        out["engine"] = held_out_z(dev, cfg, data, meta, (fin.get("overrides", {}), fin.get("effects", [])),
                                   (ov, [true] if true else []), len(true) - 1 if true else 0)
    return out


def held_out_z(dev, cfg, data, meta, base: tuple, model: tuple, n_params: int) -> dict:
    """The engine's own held-out test of ``model`` over ``base`` on the draw's data (each a pair
    of config overrides and effects; :func:`ssamb.closeloop.fit.holdout_score` on the analysis's
    split, the noise read about ``base``): ``z``, the best group's ``z_group`` and whether the
    search would call the improvement significant (:func:`ssamb.closeloop.search.improves`)."""
    from ssamb.closeloop.comparison import Comparison
    from ssamb.closeloop.data import make_split
    from ssamb.closeloop.fit import Base, holdout_score
    from ssamb.closeloop.replay import Replayer
    from ssamb.closeloop.search import improves
    from ssamb.closeloop.settings import settings_from_config

    st = settings_from_config(cfg, dev)
    rec = dev.record(data, meta, cfg, "draw")
    sp = make_split(rec, st.fit_fraction, st.discard_s, st.min_fit_s, st.min_holdout_s, "draw")
    rp = Replayer(cfg, rec, workers=1)
    try:
        cmp = Comparison.build(rec, sp, rp, range(1, st.replay_seeds + 1), st)
        cmp.calibrate_noise(base[0], base[1])
        b = Base(dict(base[0]), list(base[1]), cmp.prediction(base[0], base[1]))
        hs = holdout_score(cmp, b, cmp.prediction(model[0], model[1]), dict(model[0]), list(model[1]), n_params, st)
    finally:
        rp.close()
    return {"z": float(hs["z"]), "z_group": float(hs["z_group"]), "group": hs["group"],
            "significant": bool(improves(hs, st))}


def effect_shows(dev, cfg, ov: dict, true: dict, data, meta) -> dict:
    """Whether the drawn rig's data show its effect at the drawn size: the rig with the effect
    improves the held-out part significantly over the same rig without it, by the engine's own
    test (:func:`held_out_z`): a model the search could find at best. The truth alone decides
    it, never the analysis."""
    return held_out_z(dev, cfg, data, meta, (ov, []), (ov, [true]), len(true) - 1)


def _center(dev, cfg, path: str | None) -> dict:
    """The rig's centre: the checks' estimate on the step recording, with the parameters the real
    recordings calibrated (``path``) in place of it where they identified them."""
    arrays, meta = dev.load(next(p for p in RECORDINGS if "escalon" in p.name and "multi" not in p.name))
    out = dev.initial_estimate(dev.record(arrays, meta, cfg, "centre"), cfg)
    if path and Path(path).exists():
        rep = json.loads(Path(path).read_text())
        out.update({k: p["value"] for k, p in rep.get("parameters", {}).items()})
    return out


def _levels(rec) -> list[float]:
    """The readings at which the drawn rig's loop must be stable: the reference's lowest, median
    and highest value over the usable parts, and the readings at the parts' starts."""
    yd = np.concatenate([rec.inputs["yd"][a:b] for a, b in rec.usable])
    y0 = [float(np.mean(rec.channels["y"][a:a + 30])) for a, _ in rec.usable]
    return sorted(set(np.round(np.quantile(yd, [0.0, 0.5, 1.0]), 6).tolist()) | set(np.round(y0, 6).tolist()))


def _rig_config(dev, cfg, center, rng, rec=None, true=None, spread=1.0, why=None):
    """A rig's parameters: uniform within ``spread`` prior sd of the centre; with a record ``rec``,
    conditioned on it (the config's ``suite`` section): the force constant and the stage's
    full-scale voltage put the rig with its effect ``true`` in the force and command balance the
    recording shows at its parts' starts (:meth:`Maglev1D.balanced`), and the rig is drawn again
    when these lie more than ``suite.max_prior_sd`` prior sd from nominal, when it is no physical
    rig, or when its linearised loop is unstable at a level the reference visits (the recorded
    controller held the ball there). ``why`` (a Counter) counts the reasons of the draws refused."""
    from ssamb.config import ConfigError, apply_overrides, get
    from ssamb.maglev1d.checks import loop_poles
    from ssamb.maglev1d.config import validate

    pri = dev.priors(cfg)
    sc = cfg["suite"]
    for _ in range(50):
        ov = {}
        for key, sd in pri.items():
            nom = float(get(cfg, key))
            c = float(center.get(key, nom))
            u = rng.uniform(-1.0, 1.0) * spread
            ov[key] = c * (1.0 + u * sd) if nom != 0 else c + u * sd
        rig = apply_overrides(cfg, ov)
        if rec is not None:
            ov.update(dev.balanced(rig, rec, [true] if true else [], sc["balance_span_s"]))
            rig = apply_overrides(cfg, ov)
            off = max(abs(ov[k] / float(get(cfg, k)) - 1.0) / pri[k] for k in ("magnet.k_h", "amplifier.v_max_v"))
            if off > sc["max_prior_sd"]:
                why is not None and why.update(["balance beyond the prior"])
                continue
        try:
            validate(rig)                  # a physical rig: no negative drop, positive scales
        except ConfigError:
            why is not None and why.update(["not physical"])
            continue
        if rec is None:
            stable = loop_poles(rig, 0.005)["stable"]
        else:
            stable = all(v["stable"] for v in dev.stable_at(rig, _levels(rec), [true] if true else []).values())
        if stable:
            return ov, rig
        why is not None and why.update(["loop unstable"])
    raise RuntimeError("no stable rig in 50 draws around the centre")


def _alike(dev, rig, true, rec, drawn, seed: int, why=None) -> bool:
    """Whether the drawn rig's data levitate where the recording's ball did (the same number of
    levitated stretches) and its own model, replayed on the draw's record as the analysis replays
    it (from the states at the starts of the draw's stretches), keeps the ball off the stops in
    four realisations of the noise: a rig that strays near a stop on the recording's reference, or
    that only the recording's own start states keep up, is no rig the analysis could be asked to
    match."""
    if len(drawn.usable) != len(rec.usable):
        why is not None and why.update(["its data levitate on other stretches"])
        return False
    if any(dev.replay(rig, drawn, [true] if true else [], drawn.n, seed + j).contact for j in range(4)):
        why is not None and why.update(["its own model drops the ball on its data"])
        return False
    return True


def _effect(name: str, rng) -> dict:
    p, lo, hi, signed = SIZES[name]
    v = float(rng.uniform(lo, hi)) * (float(rng.choice([-1.0, 1.0])) if signed else 1.0)
    if name == "sensor_gain":
        v = 1.0 + v
    return {"name": name, p: v}


def _found(true: dict, rep: dict) -> list[str]:
    """Failures of a draw with an effect: not found first, or its size off."""
    eff = rep["effects"]
    if not eff:
        return [f"{true['name']} not found ({rep.get('summary', '')})"]
    e = eff[0]
    if e["name"] != true["name"]:
        named = [r["name"] for r in e.get("rivals", [])]
        among = f" (named among its rivals {named}: the data cannot tell them apart)" if true["name"] in named else ""
        return [f"found {e['name']} first, the rig has {true['name']}{among}"]
    fails = []
    for k, v in true.items():
        if k == "name" or k not in e["params"]:
            continue
        est, se = float(e["params"][k]), float(e.get("uncertainty", {}).get(k, 0.0))
        ref = v - 1.0 if k == "gain" else v
        err = est - v
        if abs(err) > max(3 * se, 0.25 * abs(ref)):
            fails.append(f"{k}: {est:.4g} +- {se:.2g} against {v:.4g}")
    if len(eff) > 1:
        fails.append(f"spurious effects beside it: {[x['name'] for x in eff[1:]]}")
    return fails


def drawable(dev, cfg, settings) -> tuple[dict, dict]:
    """Per recording's file name the effects drawn there (identifiable on it, with a size range),
    and per effect the recordings it is not drawn on, with the device's reason."""
    names, unidentifiable = {}, {}
    for path in RECORDINGS:
        arrays, meta = dev.load(path)
        rec = dev.record(arrays, meta, cfg, path.name)
        names[path.name] = []
        for n in dev.library:
            why = dev.effect_model(n, {}, rec, settings)
            if isinstance(why, str):
                unidentifiable.setdefault(n, {})[path.stem.split("_")[1]] = why
            elif n in SIZES:
                names[path.name].append(n)
    return names, unidentifiable


def make_draw(k, with_effect, seed, center, names, spread=1.0, balance=True, shown=True, consistent=True,
              attempts=ATTEMPTS) -> dict:
    """Draw ``k``'s recording, effect, rig and data (module docstring): a dict with ``path``,
    ``true``, ``ov``, ``rig``, ``data``, ``meta``, ``refused`` and ``shows``; ``data`` is None when
    no rig in ``attempts`` levitates (``failure`` says why). ``consistent``: each stretch replayed from the
    state the drawn log gives (:meth:`Maglev1D.rig_log`); else every stretch from the recording's state."""
    from ssamb.device import get_device
    from ssamb.io import DataError
    from ssamb.maglev1d.device import RIG_STREAM

    dev = get_device("maglev1d")
    cfg = dev.default_config()
    rng = np.random.default_rng([seed, k])
    paths = [p for p in RECORDINGS if names.get(p.name)] if with_effect else list(RECORDINGS)
    path = paths[int(rng.integers(len(paths)))]
    true = _effect(names[path.name][int(rng.integers(len(names[path.name])))], rng) if with_effect else None
    arrays, meta = dev.load(path)
    rec = dev.record(arrays, meta, cfg, path.name)
    why, shows = Counter(), None
    for attempt in range(attempts):      # a rig whose ball never levitates makes no data: draw again
        if attempt and true and balance:  # the effect's size is part of the rig: drawn again with it
            true = _effect(true["name"], rng)
        ov, rig = _rig_config(dev, cfg, center, rng, rec if balance else None, true, spread, why)
        # the rig's data round (the model's replays add the rounding errors: ssamb.maglev1d.physics)
        as_rig = {**rig, "replay": {**rig["replay"], "additive_quantisers": 0}}
        eff, seed_k = [true] if true else [], int(rng.integers(1, 10_000))
        out = (dev.rig_log(as_rig, rec, eff, seed_k) if consistent
               else dev.replay(as_rig, rec, eff, rec.n, seed_k, RIG_STREAM))
        data = {**arrays, **{c: out.channels[c] for c in dev.channels}}
        if out.contact:
            why.update(["its data touch a stop"])
            continue
        try:
            drawn = dev.record(data, meta, cfg, path.name)
        except DataError:
            why.update(["its data never levitate"])
            continue
        if not _alike(dev, rig, true, rec, drawn, int(rng.integers(1, 10_000)), why):
            continue
        if true and shown:
            shows = effect_shows(dev, cfg, ov, true, data, meta)
            if not shows["significant"]:
                why.update(["its effect does not show in its data"])
                continue
        break
    else:
        small = why.get("its effect does not show in its data", 0) > 0
        return {"path": path, "true": true, "refused": dict(why), "data": None,
                "failure": f"no rig that levitates{' and shows its effect' if small else ''} in {attempts} draws"}
    return {"path": path, "true": true, "ov": ov, "rig": rig, "data": data, "meta": meta, "refused": dict(why),
            "shows": shows, "rng": rng}


def run_draw(args) -> dict:
    k, with_effect, seed, center, names, spread, balance, only_rigs, shown, consistent, attempts = args
    from ssamb.closeloop import analyse
    from ssamb.device import get_device

    dev = get_device("maglev1d")
    cfg = dev.default_config()
    dr = make_draw(k, with_effect, seed, center, names, spread, balance, shown, consistent, attempts)
    path, true, why = dr["path"], dr["true"], dr["refused"]
    if dr["data"] is None:
        return {"draw": k, "effect": true, "recording": path.stem, "refused": why, "failures": [dr["failure"]]}
    ov, rig, data, meta, shows, rng = dr["ov"], dr["rig"], dr["data"], dr["meta"], dr["shows"], dr["rng"]
    if only_rigs:
        return {"draw": k, "effect": true, "recording": path.stem, "failures": [], "refused": why, "rig": ov,
                "shows": shows}
    t0 = time.perf_counter()
    try:
        rep = analyse(data, meta, cfg, device=dev)
    except Exception as exc:              # a crash is a failure of the draw, reported with the others
        return {"draw": k, "effect": true, "recording": path.stem, "failures": [f"crash: {type(exc).__name__}: {exc}"]}
    fails = _found(true, rep) if true else ([f"effects declared: {[e['name'] for e in rep['effects']]}"]
                                            if rep["effects"] else [])
    truth = against_truth(dev, cfg, rig, true, data, meta, rep, int(rng.integers(1, 10_000)), ov)
    return {"draw": k, "effect": true, "recording": path.stem, "rig": ov, "failures": fails, "truth": truth,
            "summary": rep.get("summary", ""),
            "found": [{"name": e["name"], "params": e["params"], "uncertainty": e.get("uncertainty", {}),
                       "rivals": [r["name"] for r in e.get("rivals", [])]}
                      for e in rep["effects"]],
            "parameters": {key: [p["value"], p["se"], ov.get(key)] for key, p in rep["parameters"].items()},
            "refused": why, "shows": shows, "simulations": rep["timing"]["simulations"],
            "seconds": time.perf_counter() - t0,
            "calibration_stopped_short": bool(rep.get("calibration", {}).get("stopped_short", False))}


def coverage(rows: list) -> dict:
    r"""Per calibrated parameter reported in ``rows`` (draws), the error of its estimate in its own
    standard errors, :math:`|\hat p - p| / s`, against the drawn rig's value: the count and the
    shares within 2 and 3 standard errors (0.954 and 0.997 for honest errors)."""
    z = {}
    for d in rows:
        for key, (v, se, t) in (d.get("parameters") or {}).items():
            if t is not None and se and math.isfinite(se) and se > 0:
                z.setdefault(key, []).append(abs(v - t) / se)
    return {k: {"n": len(x), "within_2": float(np.mean(np.array(x) < 2)), "within_3": float(np.mean(np.array(x) < 3))}
            for k, x in z.items()}


def summarize(res: list, drawn: list, only_rigs: bool = False) -> None:
    """Print the suite's figures for the draws ``res`` (module docstring)."""
    nodata = [d for d in res if d["failures"] and d["failures"][0].startswith("no rig that levitates")]
    refused = sum((Counter(d.get("refused", {})) for d in res), Counter())
    per = [sum((d.get("refused") or {}).values()) for d in res]
    print(f"\ndraws without data (no rig within the spread levitates on the drawn recording): {len(nodata)} of "
          f"{len(res)}; rigs refused before each draw's rig: {sum(refused.values())} ({dict(refused)}); per draw "
          f"median {np.median(per) if per else 0:.0f}, most {max(per, default=0)}")
    if only_rigs:
        return
    eff = [d for d in res if d["effect"]]
    null = [d for d in res if not d["effect"]]
    ok = sum(not d["failures"] for d in eff)
    print(f"\nwith an effect: {ok} of {len(eff)} pass ({100 * ok / max(len(eff), 1):.0f} %)")
    for half, r in (("odd (the acceptance half)", 1), ("even (the development half)", 0)):
        sel = [d for d in eff if d["draw"] % 2 == r]
        print(f"  {half} draws: {sum(not d['failures'] for d in sel)} of {len(sel)}")
    among = [d for d in eff if d["failures"] and "named among its rivals" in d["failures"][0]]
    print(f"  the truth named among the rivals of the effect found first (the data cannot tell them apart; not "
          f"counted as found): {len(among)} (odd {sum(d['draw'] % 2 for d in among)})")
    judged = [d for d in eff if d.get("truth")]
    vis = [d for d in judged if d["truth"]["visible"]]
    inv = [d for d in judged if not d["truth"]["visible"]]
    ok_vis = sum(not d["failures"] for d in vis)
    short = [d for d in vis if d["failures"] and d["truth"]["search_short"]]
    ev = [d for d in judged if d["truth"]["engine"]["significant"]]
    print(f"  the truth beats the final model on the engine's own held-out test: {len(ev)} (found "
          f"{sum(not d['failures'] for d in ev)}); not: {len(judged) - len(ev)} (the final model predicts as well: "
          f"absorbed or not shown beyond it; found {sum(not d['failures'] for d in judged if d not in ev)})")
    sh = [d for d in eff if d.get("shows")]
    if sh:
        print(f"  each effect's own held-out z over its rig without it (engine's test): median "
              f"{np.median([d['shows']['z'] for d in sh]):.1f} ({min(d['shows']['z'] for d in sh):.1f}-"
              f"{max(d['shows']['z'] for d in sh):.1f})")
    print(f"  visible in the data (the truth predicts the held-out part better than the final model, p < {ALPHA:g}): "
          f"{len(vis)}; found {ok_vis} of them ({100 * ok_vis / max(len(vis), 1):.0f} %)")
    print(f"  invisible (these data cannot show the effect beyond the final model): {len(inv)} "
          f"({sum(not d['failures'] for d in inv)} of them found anyway)")
    print(f"  missed while visible: {len(vis) - ok_vis}, of which the search stopped short (the truth also fits the "
          f"fitting part better) in {len(short)}")
    cal_short = [d for d in res if d.get("calibration_stopped_short")]
    print(f"  the calibration stopped short by its own (truth-free) check: {len(cal_short)} of "
          f"{sum('truth' in d for d in res)} draws with data ({sum(d in cal_short for d in eff)} with an effect)")
    for n in drawn:
        sel = [d for d in eff if d["effect"]["name"] == n]
        if sel:
            print(f"  {n}: {sum(not d['failures'] for d in sel)} of {len(sel)}")
    alarms = sum(bool(d.get("found")) for d in null)
    nj = [d for d in null if d.get("truth")]
    print(f"noise only: the truth beats the final model on the engine's own held-out test in "
          f"{sum(d['truth']['engine']['significant'] for d in nj)} of {len(nj)} draws with data (the calibration "
          f"alone ends short of the rig); the final model drops the ball in 4 or more of {REPLAYS} replays in "
          f"{sum(d['truth']['contacts']['final'] >= REPLAYS // 2 for d in nj)}")
    print(f"noise only: {alarms} of {len(null)} declared an effect"
          f"{f' ({sum(d in nodata for d in null)} without data: no rig that levitates)' if nodata else ''}")
    for label, sel in (("noise-only draws", [d for d in res if not d["effect"]]),
                       ("draws whose effect was found", [d for d in res if d["effect"] and not d["failures"]])):
        cov = coverage(sel)
        if cov:
            n = sum(c["n"] for c in cov.values())
            w2 = sum(c["n"] * c["within_2"] for c in cov.values()) / n
            w3 = sum(c["n"] * c["within_3"] for c in cov.values()) / n
            print(f"coverage of the calibrated parameters' standard errors, {label}: {n} estimates, within 2 se "
                  f"{w2:.2f}, within 3 se {w3:.2f} (honest: 0.95, 0.997); " + ", ".join(
                      f"{k} {c['within_3']:.2f} of {c['n']}" for k, c in cov.items()))


def _override_config(cls, items: list) -> None:
    """Every default configuration of the device class ``cls`` with the ``KEY=VALUE`` overrides
    ``items`` (YAML values) applied: the analyses and the rigs of every draw (the worker processes
    are forked after this)."""
    import yaml

    from ssamb.config import apply_overrides

    ov = {k: yaml.safe_load(v) for k, v in (it.split("=", 1) for it in items)}
    orig = cls.default_config
    cls.default_config = lambda self: apply_overrides(orig(self), ov)
    print(f"configuration overrides: {ov}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draws", type=int, default=24, help="draws with an effect")
    ap.add_argument("--null", type=int, default=20, help="draws without an effect")
    ap.add_argument("--seed", type=int, default=20261126)
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--center", default=str(REPO / "results" / "rigs" / "maglev1d" / "closeloop.json"),
                    help="closeloop.json of the real rig (its parameters are the rigs' centre)")
    ap.add_argument("--out", default="maglev_suite.jsonl")
    ap.add_argument("--spread", type=float, default=1.0,
                    help="rigs within this many prior standard deviations of the centre (1: the suite; "
                         "smaller: a diagnostic of the effect search alone)")
    ap.add_argument("--unbalanced", action="store_true",
                    help="rigs not conditioned on the recording's balance and levels (the suite before that)")
    ap.add_argument("--any-size", action="store_true",
                    help="keep an effect whose size its rig's data do not show (effect_shows)")
    ap.add_argument("--recording-states", action="store_true",
                    help="replay every stretch of a rig's log from the recording's controller state instead of "
                         "the state its own log gives (the suite before Maglev1D.rig_log)")
    ap.add_argument("--null-first", action="store_true",
                    help="run the noise-only draws before the draws with an effect (the same draws)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a key of the device's configuration in every analysis and rig (YAML value; "
                         "e.g. closeloop.rivals=false), repeatable")
    ap.add_argument("--summary", metavar="JSONL", help="print the figures of a finished run's --out file, run nothing")
    ap.add_argument("--attempts", type=int, default=ATTEMPTS,
                    help="rigs drawn for one draw at most before it is left without data")
    ap.add_argument("--only-rigs", action="store_true",
                    help="draw the rigs and their data, count the refused draws, analyse nothing")
    a = ap.parse_args()
    from ssamb.closeloop.settings import settings_from_config
    from ssamb.device import get_device

    dev = get_device("maglev1d")
    if a.set:
        _override_config(type(dev), a.set)
    cfg = dev.default_config()
    settings = settings_from_config(cfg, dev)
    names, unidentifiable = drawable(dev, cfg, settings)
    drawn = sorted({n for v in names.values() for n in v})
    if a.summary:
        summarize([json.loads(line) for line in open(a.summary)], drawn)
        sys.exit(0)
    center = _center(dev, cfg, a.center)
    print(f"effects drawn: {', '.join(drawn)}", flush=True)
    for n, why in unidentifiable.items():
        recs = sorted(why)
        where = "on every recording" if len(recs) == len(RECORDINGS) else f"on {', '.join(recs)}"
        print(f"not drawn {where} ({n}): {next(iter(why.values()))}", flush=True)
    opts = (a.spread, not a.unbalanced, a.only_rigs, not a.any_size, not a.recording_states, a.attempts)
    jobs = [(k, True, a.seed, center, names, *opts) for k in range(a.draws)]
    jobs += [(a.draws + k, False, a.seed, center, names, *opts) for k in range(a.null)]
    if a.null_first:
        jobs = jobs[a.draws:] + jobs[:a.draws]
    t0 = time.perf_counter()
    res = []
    with mp.get_context("fork").Pool(a.processes) as pool, open(a.out, "a") as fh:
        for d in pool.imap_unordered(run_draw, jobs):
            res.append(d)
            fh.write(json.dumps(d, default=float) + "\n")
            fh.flush()
            tr = d.get("truth")
            vs = (f" [truth vs final: cost ratio fit {tr['fit']['cost_ratio']:.3f} "
                  f"(p {tr['fit']['p_truth_better']:.2g}), "
                  f"held out {tr['holdout']['cost_ratio']:.3f} (p {tr['holdout']['p_truth_better']:.2g})"
                  f"; stop hit by truth {tr['contacts']['truth']}, final {tr['contacts']['final']} of {REPLAYS}"
                  f"; engine's held-out z of the truth over the final model {tr['engine']['z']:.1f}"
                  f" (group {tr['engine']['group']} {tr['engine']['z_group']:.1f})"
                  f"{'' if tr['visible'] or not d['effect'] else ': INVISIBLE'}]") if tr else ""
            ref = d.get("refused") or {}
            rd = f" [{d['recording']}; rigs redrawn {sum(ref.values())}: {ref}]" if ref else f" [{d['recording']}]"
            print(f"draw {d['draw']:3d} {d['effect']['name'] if d['effect'] else 'none':18s} "
                  f"{'PASS' if not d['failures'] else 'FAIL ' + '; '.join(d['failures'])}{vs}{rd}", flush=True)
    summarize(res, drawn, a.only_rigs)
    secs = [d.get("seconds", math.nan) for d in res]
    print(f"wall {time.perf_counter() - t0:.0f} s on {a.processes} processes; median {np.nanmedian(secs):.0f} s per "
          f"analysis; load average {os.getloadavg()[0]:.1f}")
    sys.exit(0)


if __name__ == "__main__":
    main()
