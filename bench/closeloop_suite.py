"""Close the loop's randomized acceptance suite: rigs that are not the model, running experiments a
rig runs, judged against the truth the suite knows.

    python bench/closeloop_suite.py --draws 60 --null 50 --procs 2 --out suite_dir
    python bench/closeloop_suite.py --summary suite_dir        # the summary of what is there
    python bench/closeloop_suite.py --draws 60 --only 2,6,58 --out again   # these draws alone
    python bench/closeloop_suite.py --draws 60 --only 2,6 --design-seeds 0,1,2 --out seeds  # the estimator's seeds

Each **draw** (:func:`run_draw`) makes a rig: every calibratable nominal parameter perturbed
uniformly within :data:`ssamb.rig.SUITE_PERTURB`, one library effect (none in a quarter of the
draws of each kind) drawn with its parameters (:func:`ssamb.rig.draw_effect`), and an experiment
of the draw's kind (``--kinds``; draws cycle through them) with its band, amplitude and excited
axes drawn (:func:`ssamb.rig.draw_experiment`), logged with noise. The analysis
(:func:`ssamb.closeloop.analyse`, the default settings) sees only the data. A draw **passes** when

1. every reported calibrated parameter is within three standard errors or a third of its
   perturbation of the truth the model can see (:func:`ssamb.rig.effective_truth`);
2. every reported effect is the true one, its parameters within three standard errors or a
   practical tolerance (10 %, a delay 3 us); a true effect not reported is a failure only when the
   data show it: the truth's prediction beats the final model's on the held-out part
   significantly (the improvement test of an effect, :func:`ssamb.closeloop.fit.holdout_score`).
   An effect reported with the true one among its ``rivals`` (the data cannot tell them apart,
   both named) counts as the true one, judged by the rival's parameters and standard errors;
   the summary counts such draws;
3. the oracle: the final model's held-out cost is not significantly above the truth's (same test);
   recorded beside it, the truth's advantage beyond what an estimate from the fitting part would
   cost on the held-out part (``z_beyond_uncertainty``: :func:`ssamb.closeloop.excess.truth_advantage`);
4. per channel (each coil, each position, each controller output), the held-out rms error after
   is at most half of before or at most 1.2 times the floor, the floor being the truth's own
   held-out error (replays with the truth); the floor the data estimate (``noise_rms``) is
   recorded beside it.

**Null draws** (``--null``): the nominal model, no effect, an experiment of each kind in turn:
a declared effect is a false alarm.

Every draw writes one JSON line as it ends (``OUT/w<i>.jsonl`` per process: partial results
survive), with the wall time and the load average; each process has its own
``NUMBA_CACHE_DIR``. The summary (printed at the end, or alone with ``--summary``) gives the
pass rate overall and per kind, the coverage of 2-standard-error intervals per parameter and per
effect parameter, and the false alarms.

**The estimator's own seeds** (``--design-seeds``): the analysis is a simulation-based
estimate, and its replays' seeds and finite-difference designs (``closeloop.estimate.design_seed``)
are a random choice of the analysis, not of the rig. Each draw is then analysed once per seed
(the same rig data); the summary adds the pass rate over the analyses, the draws whose verdict
depends on the seed, and per parameter the spread of its estimates between the seeds of one
draw against the standard errors reported with them (``between/se``: the ratio of the pooled
between-seed variance to the mean reported variance; above 1 the reported errors cannot cover
the estimator's own randomness; its p-value says whether a ratio above 1 is more than the few
seeds' chance).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import stats

REPO = Path(__file__).resolve().parent.parent


def _z_crit() -> float:
    """The oracle's one-sided level: the repository's ``closeloop.alpha_accept``."""
    from ssamb.config import load_config

    return float(stats.norm.isf(load_config()["closeloop"]["alpha_accept"]))


# -- one draw ---------------------------------------------------------------------------------
def _relative(cfg: dict, key: str, value: float, se: bool = False) -> float:
    from ssamb.config import get

    nominal = float(get(cfg, key))
    if nominal == 0:
        return value
    return value / abs(nominal) if se else value / nominal - 1


def make_rig(tmp: Path, name: str, exp: dict, effects: list, overrides: dict, noise_seed: int):
    """Rig data ``(arrays, meta, scenario)`` of an experiment (:func:`ssamb.rig.draw_experiment`)."""
    import yaml

    from ssamb.rig import SUITE_NOISE, load_scenario, rig_data

    sc = {"config": str(REPO / "config.yaml"), "experiment": exp["experiment"], "effects": effects,
          "noise": {**SUITE_NOISE, "seed": int(noise_seed)}, "overrides": overrides}
    if exp.get("duration_s") is not None:
        sc["duration_s"] = float(exp["duration_s"])
    p = tmp / f"{name}.yaml"
    p.write_text(yaml.safe_dump(sc))
    scenario = load_scenario(p)
    return (*rig_data(scenario), scenario)


def truth_model(cfg: dict, truth: dict) -> dict:
    """Config overrides of the truth the model can see (relative changes -> values)."""
    from ssamb.config import get

    out = {}
    for key, d in truth.items():
        nominal = float(get(cfg, key))
        out[key] = nominal * (1 + d) if nominal != 0 else nominal + d
    return out


def effect_checks(true: list, rep: dict) -> tuple[list, list, list]:
    """``(failures, coverage entries, missed true effects)`` of the reported effects against the
    true ones (module docstring, 2)."""
    fails, cov, missed = [], [], []
    by_name = {}
    names = {t["name"] for t in true}
    for e in rep["effects"]:
        twin = next((r for r in e.get("rivals", []) if e["name"] not in names and r["name"] in names), None)
        if twin is not None:      # named beside the effect reported first: the data cannot tell them apart
            e = {"name": twin["name"], "params": twin["params"], "uncertainty": twin.get("uncertainty", {}),
                 "via_rival_of": e["name"]}
        by_name.setdefault(e["name"], []).append(e)
    for n in by_name:
        if n not in names and not (n == "sensor_gain" and False):
            fails.append(f"spurious effect {n}: {[e['params'] for e in by_name[n]]}")

    def check(label, est, se, truth, tol):
        z = (est - truth) / se if se > 0 else (0.0 if est == truth else math.inf)
        cov.append({"param": label, "est": est, "se": se, "truth": truth, "z": z})
        if abs(est - truth) > max(3 * se, tol):
            fails.append(f"{label}: {est:.4g} +- {se:.2g}, truth {truth:.4g}")

    for t in true:
        got = by_name.get(t["name"], [])
        if not got:
            missed.append(t)
            continue
        n = t["name"]
        if n in ("sensor_delay", "sensor_gain"):
            key = "delay_s" if n == "sensor_delay" else "gain"
            t_axes = ("x", "y") if t["axis"] == "both" else (t["axis"],)
            seen = set()
            for e in got:
                per = e.get("per_axis") or {e["params"]["axis"]: {key: e["params"][key], "se": e["uncertainty"][key]}}
                for ax, d in per.items():
                    seen.add(ax)
                    if n == "sensor_gain" and ax == "y":
                        continue          # the DCM calibration's own error: judged with the calibration gain
                    truth = t[key] if ax in t_axes else (0.0 if n == "sensor_delay" else 1.0)
                    tol = 3e-6 if n == "sensor_delay" else 0.1 * abs(t[key] - 1.0)
                    check(f"{n}.{key}.{ax}", float(d[key]), float(d["se"]), truth, tol)
            if any(ax not in seen for ax in t_axes if not (n == "sensor_gain" and ax == "y")):
                missed.append({**t, "axis": ",".join(ax for ax in t_axes if ax not in seen)})
        elif n == "static_load":
            e = got[0]
            f = math.hypot(t["fx_n"], t["fy_n"])
            for k in ("fx_n", "fy_n"):
                se = float(e["uncertainty"].get(k, 0.0))
                if se > 0 and k in e["params"]:
                    check(f"static_load.{k}", float(e["params"][k]), se, t[k], 0.1 * f)
        elif n == "unbalance":
            e = got[0]
            check("unbalance.mass_ecc_kgm", e["params"]["mass_ecc_kgm"], e["uncertainty"]["mass_ecc_kgm"],
                  t["mass_ecc_kgm"], 0.1 * t["mass_ecc_kgm"])
            check("unbalance.speed_hz", e["params"]["speed_hz"], e["uncertainty"]["speed_hz"], t["speed_hz"],
                  0.01 * t["speed_hz"])
        else:
            key = {"amplifier_deadtime": "deadtime_s", "cross_coupling": "coefficient"}[n]
            e = got[0]
            check(f"{n}.{key}", e["params"][key], e["uncertainty"][key], t[key], 0.1 * t[key])
    return fails, cov, missed


def draw_rig(tmp: Path, k: int, kind: str, seed: int, cfg: dict, null: bool = False) -> dict:
    """Draw ``k`` of the suite ``seed`` (module docstring): its experiment, perturbation
    (``overrides`` in values, ``delta`` relative), effects and logged data (``arrays``, ``meta``,
    ``scenario``)."""
    from ssamb.rig import SUITE_EFFECTS, draw_effect, draw_experiment, draw_perturbation

    rng = np.random.default_rng([seed, 29 if null else 23, k])
    exp = draw_experiment(kind, rng)
    if null:
        ov, delta = {}, {}
        true = []
    else:
        ov, delta = draw_perturbation(rng, cfg)
        with_effect = (k // 4) % 4 != 3
        true = [draw_effect(SUITE_EFFECTS[int(rng.integers(len(SUITE_EFFECTS)))], rng)] if with_effect else []
    noise_seed = int(rng.integers(1, 100_000))
    arrays, meta, scenario = make_rig(tmp, f"d{k}", exp, true, ov, noise_seed)
    return {"experiment": exp, "overrides": ov, "delta": delta, "effects": true, "arrays": arrays, "meta": meta,
            "scenario": scenario}


def run_draw(tmp: Path, k: int, kind: str, seed: int, null: bool = False, workers: int = 1,
             progress: bool = False, design_seed: int | None = None) -> dict:
    """One draw (module docstring): its experiment, truth, the analysis's findings and the verdict;
    ``design_seed`` sets the estimator's ``closeloop.estimate.design_seed`` (default: the config's)."""
    from scipy import stats

    from ssamb.closeloop import _analyse
    from ssamb.closeloop.excess import truth_advantage
    from ssamb.closeloop.fit import Base
    from ssamb.config import load_config
    from ssamb.rig import effective_truth

    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    cfg = load_config()
    if design_seed is not None:
        cl = cfg["closeloop"]
        cfg = {**cfg, "closeloop": {**cl, "estimate": {**(cl.get("estimate") or {}), "design_seed": int(design_seed)}}}
    d = draw_rig(tmp, k, kind, seed, cfg, null)
    exp, true, delta, arrays, meta, scenario = (d[x] for x in ("experiment", "effects", "delta", "arrays", "meta",
                                                               "scenario"))
    rep, art = _analyse(arrays, meta, cfg, source=f"draw {k}", workers=workers, progress=progress)
    out = {"draw": k, "kind": kind, "null": null, "design_seed": design_seed, "experiment": exp, "effect": true,
           "perturbation": delta,
           "found": [e["name"] for e in rep["effects"]], "effects_found": rep["effects"], "summary": rep["summary"],
           "unexplained": rep["unexplained"], "simulations": rep["timing"]["simulations"],
           "rounds": [{"round": r["round"], "ranking": r["ranking"],
                       "candidates": [(c["name"], c.get("holdout_z"), c.get("holdout_z_group"), c.get("reasons"))
                                      for c in r["candidates"]]} for r in rep["rounds"]],
           "optimum": rep.get("optimum"), "misfit_ratio": rep.get("misfit", {}).get("ratio"),
           "via_rival": [(e["name"], r["name"]) for e in rep["effects"] for r in e.get("rivals", [])
                         if r["name"] in {t["name"] for t in true} and e["name"] not in {t["name"] for t in true}]}
    # the truth the model can see: a y sensor gain the analysis did not name is the DCM calibration's
    g_true = next((t["gain"] for t in true if t["name"] == "sensor_gain" and t["axis"] in ("y", "both")), 1.0)
    g_found = next((e.get("per_axis", {}).get("y", e["params"])["gain"] for e in rep["effects"]
                    if e["name"] == "sensor_gain" and e["params"]["axis"] in ("y", "both")), 1.0)
    base_delta = {key: delta.get(key, 0.0) for key in cfg["closeloop"]["calibration"]}
    truth = effective_truth(scenario, base_delta, g_true / g_found)
    fails, cov = [], []
    for key, p in rep["parameters"].items():
        est, se = _relative(cfg, key, p["value"]), _relative(cfg, key, p["se"], se=True)
        err = est - truth[key]
        cov.append({"param": key, "est": est, "se": se, "truth": truth[key], "z": err / se if se > 0 else math.inf})
        if not (abs(err) <= abs(delta.get(key, truth[key])) / 3 or abs(err) <= 3 * se):
            fails.append(f"{key}: estimate {est:+.4g}, truth {truth[key]:+.4g}, se {se:.2g}")
    efails, ecov, missed = effect_checks(true, rep)
    fails += efails
    # the oracle: the truth (as the model sees it, its effects as they are) replayed like the final model
    cmp, search, st = art["comparison"], art["search"], art["settings"]
    truth_ov = truth_model(cfg, effective_truth(scenario, base_delta, 1.0))
    truth_eff = [dict(e) for e in true]
    try:
        tpred = cmp.prediction(truth_ov, truth_eff)
        final = Base(search.overrides, search.effects, search.final)
        hs = truth_advantage(cmp, final, search.joint.get("point"), tpred, truth_ov, truth_eff, st)
    finally:
        cmp.replay.close()
    z_crit = float(stats.norm.isf(st.alpha_accept))
    out["oracle"] = {"z_truth_vs_final": hs["z"], "z_beyond_uncertainty": hs["z_excess"], "spread": hs["spread"],
                     "chi2_hold_final": hs["per_view"] and sum(
        v["chi2_before"] for v in hs["per_view"].values()), "chi2_hold_truth": sum(
        v["chi2_after"] for v in hs["per_view"].values()), "chi2_fit_final": hs["chi2_fit_before"],
        "chi2_fit_truth": hs["chi2_fit_after"], "n_hold": sum(v["n"] for v in hs["per_view"].values()),
        "n_fit": hs["n_fit"], "per_view": hs["per_view"]}
    if hs["z"] > z_crit:
        fails.append(f"oracle: the truth explains held-out data better than the final model (z = {hs['z']:.1f})")
    for t in missed:
        if hs["z"] > z_crit:
            fails.append(f"missed {t['name']} ({t}) though the data show it")
    out["missed"] = missed
    # per channel against the floor: the truth's own held-out error
    from ssamb.closeloop.residual import channel_errors

    rec, split = art["record"], art["split"]
    truth_err = channel_errors(rec.channels, tpred, split.hold, rec.device)
    chans = {}
    for c in rec.device.channels:
        b, a = rep["error_before"][c]["rms"], rep["error_after"][c]["rms"]
        fl = truth_err[c]["rms"]
        chans[c] = {"before": b, "after": a, "floor_truth": fl, "noise_rms": rep["error_after"][c].get("noise_rms")}
        if b > 1.5 * fl and a > max(0.5 * b, 1.2 * fl):
            fails.append(f"held-out {c}: {b:.3g} -> {a:.3g} (floor {fl:.3g})")
    out.update(channels=chans, coverage=cov + ecov, failures=fails, truth=truth,
               wall_s=time.perf_counter() - t0, load=[load0, os.getloadavg()[0]])
    if null and rep["effects"]:
        out["false_alarm"] = True
    return out


# -- the suite --------------------------------------------------------------------------------
def _tasks(args) -> list:
    kinds = args.kinds.split(",")
    t = [(k, kinds[k % len(kinds)], False) for k in range(args.start, args.start + args.draws)]
    t += [(k, kinds[k % len(kinds)], True) for k in range(args.start, args.start + args.null)]
    if args.only:
        keep = {int(k) for k in args.only.split(",")}
        t = [x for x in t if x[0] in keep]
    seeds = [int(x) for x in args.design_seeds.split(",")] if args.design_seeds else [None]
    return [(*x, ds) for x in t for ds in seeds]


def _worker(args) -> None:
    out = Path(args.out) / f"w{args.worker}.jsonl"
    tasks = _tasks(args)[args.worker::args.procs]
    with tempfile.TemporaryDirectory() as tmp:
        for k, kind, null, ds in tasks:
            try:
                d = run_draw(Path(tmp), k, kind, args.seed, null, args.workers, design_seed=ds)
            except Exception as exc:           # a crash is a failure of the draw, reported with the others
                import traceback

                d = {"draw": k, "kind": kind, "null": null, "design_seed": ds,
                     "failures": [f"crash: {type(exc).__name__}: {exc}"], "traceback": traceback.format_exc()}
            with open(out, "a") as fh:
                fh.write(json.dumps(d, default=float) + "\n")
            seed_note = "" if ds is None else f", design seed {ds}"
            print(f"draw {k} ({kind}{', null' if null else ''}{seed_note}): "
                  f"{'pass' if not d['failures'] else d['failures']}"
                  f" ({d.get('wall_s', 0):.0f} s)", flush=True)


def summary(out_dir: Path) -> dict:
    """The suite's figures from every ``*.jsonl`` in ``out_dir`` (module docstring)."""
    rows = []
    for f in sorted(Path(out_dir).glob("*.jsonl")):
        rows += [json.loads(line) for line in f.read_text().splitlines() if line.strip()]
    main = [r for r in rows if not r.get("null")]
    null = [r for r in rows if r.get("null")]
    res = {"draws": len(main), "passed": sum(not r["failures"] for r in main), "per_kind": {}, "coverage": {},
           "null_draws": len(null), "false_alarms": sum(bool(r.get("found")) for r in null)}
    for r in main:
        d = res["per_kind"].setdefault(r["kind"], [0, 0])
        d[0] += not r["failures"]
        d[1] += 1
    for r in main:
        for c in r.get("coverage", []):
            d = res["coverage"].setdefault(c["param"], [0, 0])
            d[0] += abs(c["z"]) <= 2
            d[1] += 1
    res["failing"] = [(r["draw"], r["kind"], r["failures"]) for r in main if r["failures"]]
    beyond = {r["draw"]: r["oracle"]["z_beyond_uncertainty"] for r in main
              if "z_beyond_uncertainty" in r.get("oracle", {})}
    z_crit = _z_crit()
    res["oracle_beyond"] = [sum(z > z_crit for z in beyond.values()), len(beyond),
                            sorted(k for k, z in beyond.items() if z > z_crit), z_crit]
    res["via_rival"] = [(r["draw"], r["kind"], r["via_rival"], not r["failures"]) for r in main if r.get("via_rival")]
    res["null_found"] = [(r["draw"], r["kind"], r["found"]) for r in null if r.get("found")]
    res["null_crashed"] = [(r["draw"], r["failures"]) for r in null
                           if r.get("failures") and "crash" in r["failures"][0]]
    res["seeds"] = seed_dependence(main)
    return res


def seed_dependence(rows: list) -> dict | None:
    r"""What the estimator's own seeds change (module docstring), from the analyses of draws run
    at more than one ``design_seed``: ``{analyses, draws, verdict_differs, per_parameter}`` with,
    per parameter reported in at least two seeds of a draw, ``[between/se, estimates, draws, p]``
    (the seeds' sample variance over the mean reported variance within each draw, pooled by degrees
    of freedom; ``p`` the chance of a ratio at least this large if the reported errors were the
    seeds' spread: its sum over the draws, each times its degrees of freedom, is then about
    :math:`\chi^2` with the degrees of freedom summed -- few seeds make a ratio of a few no evidence);
    None when no draw has two seeds."""
    by_draw: dict = {}
    for r in rows:
        by_draw.setdefault(r["draw"], []).append(r)
    multi = {k: v for k, v in by_draw.items() if len({r.get("design_seed") for r in v}) > 1}
    if not multi:
        return None
    acc: dict = {}                  # name -> [sum of dof * ratio, dof, estimates, draws]
    for v in multi.values():
        ests: dict = {}
        for r in v:
            for c in r.get("coverage", []):
                ests.setdefault(c["param"], []).append((c["est"], c["se"]))
        for name, e in ests.items():
            x = np.array(e)
            if len(x) < 2 or not np.all(np.isfinite(x)) or not np.all(x[:, 1] > 0):
                continue
            # within one draw, scale-free: the seeds' sample variance over the mean reported variance
            ratio = float(np.var(x[:, 0], ddof=1) / np.mean(x[:, 1] ** 2))
            a = acc.setdefault(name, [0.0, 0, 0, 0])
            a[0] += (len(x) - 1) * ratio
            a[1] += len(x) - 1
            a[2] += len(x)
            a[3] += 1
    per = {n: [a[0] / a[1], a[2], a[3], float(stats.chi2.sf(a[0], a[1]))] for n, a in acc.items()}
    differs = sorted(k for k, v in multi.items() if len({not r["failures"] for r in v}) > 1)
    return {"analyses": sum(len(v) for v in multi.values()), "draws": len(multi),
            "passed": sum(not r["failures"] for v in multi.values() for r in v),
            "verdict_differs": differs, "per_parameter": per}


def print_summary(res: dict) -> None:
    n = max(res["draws"], 1)
    print(f"draws: {res['draws']}, passed {res['passed']} ({100 * res['passed'] / n:.0f} %)")
    for kind, (p, m) in sorted(res["per_kind"].items()):
        print(f"  {kind}: {p} of {m} ({100 * p / max(m, 1):.0f} %)")
    print("coverage of 2-standard-error intervals (p: two-sided binomial test against 95 %):")
    for name, (p, m) in sorted(res["coverage"].items()):
        print(f"  {name}: {p} of {m} ({100 * p / max(m, 1):.0f} %; p {stats.binomtest(p, m, 0.95).pvalue:.2g})")
    b = res.get("oracle_beyond")
    if b and b[1]:
        print(f"oracle beyond the estimation error (z_beyond_uncertainty > {b[3]:.2f}): {b[0]} of {b[1]} draws, "
              f"draws {b[2]}")
    print(f"null draws: {res['null_draws']}, false alarms {res['false_alarms']}")
    for d in res["via_rival"]:
        print(f"  draw {d[0]} ({d[1]}): the true effect named as a rival of the one reported first, {d[2]}"
              f"{'' if d[3] else ' (failed otherwise)'}")
    for d in res["failing"]:
        print(f"  failed draw {d[0]} ({d[1]}): {d[2]}")
    for d in res["null_found"]:
        print(f"  false alarm in null draw {d[0]} ({d[1]}): {d[2]}")
    sd = res.get("seeds")
    if sd:
        print(f"the estimator's seeds: {sd['draws']} draws analysed at several design seeds, {sd['passed']} of "
              f"{sd['analyses']} analyses pass; the verdict depends on the seed in {len(sd['verdict_differs'])} "
              f"draws {sd['verdict_differs']}")
        for name, (ratio, n, m, p) in sorted(sd["per_parameter"].items()):
            print(f"  {name}: between-seed variance / reported se^2 = {ratio:.2f} ({n} estimates in {m} draws; "
                  f"p {p:.2g} if the errors covered the seeds' spread)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draws", type=int, default=60, help="draws with a rig off the model (effects in 3 of 4)")
    ap.add_argument("--start", type=int, default=0, help="first draw number")
    ap.add_argument("--null", type=int, default=0, help="noise-only draws from the nominal model")
    ap.add_argument("--kinds", default="multisine,pulses,sweep,rest", help="experiment kinds, cycled")
    ap.add_argument("--seed", type=int, default=20260101, help="the suite's seed")
    ap.add_argument("--procs", type=int, default=2, help="processes (each its own numba cache)")
    ap.add_argument("--workers", type=int, default=1, help="replay workers per analysis")
    ap.add_argument("--out", default="closeloop_suite", help="folder of the per-process JSON lines")
    ap.add_argument("--only", metavar="K,K,...", help="run only these draw numbers of the ranges (the same draws: "
                    "a draw's number sets its rig and experiment)")
    ap.add_argument("--summary", metavar="DIR", help="print the summary of DIR and exit")
    ap.add_argument("--one", type=int, metavar="K", help="run draw K alone, with the analysis's progress, and print it")
    ap.add_argument("--kind", help="with --one: the draw's experiment kind (default: as the suite cycles)")
    ap.add_argument("--design-seeds", metavar="S,S,...", help="analyse each draw once per estimator design seed "
                    "(closeloop.estimate.design_seed; default: the config's, once); with --one, the first")
    ap.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.summary:
        print_summary(summary(Path(args.summary)))
        return
    if args.one is not None:
        kinds = args.kinds.split(",")
        with tempfile.TemporaryDirectory() as tmp:
            ds = int(args.design_seeds.split(",")[0]) if args.design_seeds else None
            d = run_draw(Path(tmp), args.one, args.kind or kinds[args.one % len(kinds)], args.seed,
                         args.null > 0, args.workers, progress=True, design_seed=ds)
        print(json.dumps(d, default=float, indent=1))
        return
    if args.worker is not None:
        _worker(args)
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    procs = []
    for i in range(args.procs):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(out / f"numba_{i}"), NUMBA_NUM_THREADS="1",
                   PYTHONPATH=os.pathsep.join([str(REPO)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
        cmd = [sys.executable, __file__, "--worker", str(i)] + [a for a in sys.argv[1:]]
        procs.append(subprocess.Popen(cmd, env=env))
    t0 = time.perf_counter()
    for p in procs:
        p.wait()
    print(f"suite wall time {time.perf_counter() - t0:.0f} s; load average {os.getloadavg()[0]:.2f} on "
          f"{os.cpu_count()} CPUs")
    print_summary(summary(out))


if __name__ == "__main__":
    main()
