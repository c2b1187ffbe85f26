"""The estimator's noise floor checked against the truth: is the true model "far above" it?

    python bench/closeloop_floor.py --seed 20261215 --draws 0-7 --anchors 3
    python bench/closeloop_floor.py --seed 20261211 --draws 55 --groups     # each group's share

A fit that ends far above its noise floor is taken for one that stopped short of a better
model: it is given more iterations, wider steps, other basins (``closeloop.estimate``,
``short_alpha``). The test must then hold for the truth at the rate it claims. For each draw of
the acceptance suite (``bench/closeloop_suite.py``: the same rigs), the truth as the model can
see it (the suite's oracle model) is replayed on the fitting part as a fit's centre is, the mean
of ``centre_runs`` replays with their own seeds, ``--anchors`` times with other seeds. Each
anchor's cost is set against

* the floor of :func:`ssamb.closeloop.estimate.noise_floor` and its effective degrees of freedom
  (the replays' own noise where it exceeds the whitening's unit, and the modes that move whole
  views together), and
* the floor of independent entries of unit noise, :math:`N(1 + \\rho/m)` with :math:`N` degrees
  of freedom,

and flagged far above each by :func:`ssamb.closeloop.estimate._far_above` at ``short_alpha``.
With a right floor the truth is flagged in about that share of the anchors. Prints one line per
anchor (``--groups``: also each group's cost per entry and replay variance), with the independent
entries a replay's noise is worth (:func:`ssamb.closeloop.estimate.effective_entries`, which sets
the threshold of a determined direction), and the shares.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import closeloop_suite as suite  # noqa: E402


def _draws(spec: str) -> list:
    out = []
    for part in spec.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def truth_anchors(k: int, seed: int, kind: str, anchors: int, groups: bool = False) -> list:
    """The anchors of draw ``k``'s truth: per anchor its cost, both floors, degrees of freedom and
    flags (dicts)."""
    from ssamb.closeloop import comparison_of
    from ssamb.closeloop.estimate import EstimateSettings, _far_above, effective_entries, noise_floor, replay_noise
    from ssamb.config import load_config
    from ssamb.rig import effective_truth

    cfg = load_config()
    with tempfile.TemporaryDirectory() as tmp:
        d = suite.draw_rig(Path(tmp), k, kind, seed, cfg)
    c = comparison_of(d["arrays"], d["meta"], cfg, source=f"draw {k}")
    cmp, st = c["comparison"], c["settings"]
    est = EstimateSettings(**st.estimate)
    base_delta = {key: d["delta"].get(key, 0.0) for key in cfg["closeloop"]["calibration"]}
    tov = suite.truth_model(cfg, effective_truth(d["scenario"], base_delta, 1.0))
    teff = [dict(e) for e in d["effects"]]
    try:
        many = cmp.evaluate_many(cmp.fit, lambda theta: (tov, teff))
        gs = cmp.groups(cmp.fit)
        m = est.centre_runs
        out = []
        for a in range(anchors):
            C = np.array(many([(None, 10_000 * a + 500 + j) for j in range(m)]))
            C = C[np.all(np.isfinite(C), axis=1)]
            if len(C) < 2:
                out.append({"draw": k, "anchor": a, "infeasible": True})
                continue
            r = C.mean(axis=0)
            cost, n = float(r @ r), len(r)
            vg, t2, diag = replay_noise(C, gs)
            sizes = np.array([len(g) for g in gs])
            f, nu = noise_floor(sizes, vg, t2, len(C))
            f_ind = n * (1.0 + float(np.mean(C.var(axis=0, ddof=1))) / len(C))
            row = {"draw": k, "kind": kind, "anchor": a, "cost": cost, "n": n, "floor": f, "dof": nu,
                   "replay_entries": effective_entries(sizes, vg, t2, diag),
                   "floor_independent": f_ind, "far": _far_above(cost, n, f, est.short_alpha, nu),
                   "far_independent": _far_above(cost, n, f_ind, est.short_alpha)}
            if groups:
                row["groups"] = [(len(g), float(r[g] @ r[g]) / len(g), float(v)) for g, v in zip(gs, vg)]
            out.append(row)
        return out
    finally:
        c["replay"].close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=20260101, help="the suite's seed")
    ap.add_argument("--draws", default="0-3", help="draw numbers: K,K or K-K")
    ap.add_argument("--kinds", default="multisine,pulses,sweep,rest", help="experiment kinds, cycled as the suite")
    ap.add_argument("--anchors", type=int, default=3, help="anchors (sets of centre runs) per draw")
    ap.add_argument("--groups", action="store_true", help="print each group's cost and replay variance")
    args = ap.parse_args()
    kinds = args.kinds.split(",")
    rows = []
    for k in _draws(args.draws):
        for r in truth_anchors(k, args.seed, kinds[k % len(kinds)], args.anchors, args.groups):
            rows.append(r)
            if r.get("infeasible"):
                print(f"draw {k} anchor {r['anchor']}: the truth's replays drop the body", flush=True)
                continue
            print(f"draw {k:3d} ({r['kind']:9s}) anchor {r['anchor']}: cost {r['cost']:9.1f} (N {r['n']}); floor "
                  f"{r['floor']:7.1f}, {r['dof']:6.1f} dof: {'FAR ABOVE' if r['far'] else 'within'}; independent "
                  f"entries {r['floor_independent']:7.1f}, {r['n']} dof: "
                  f"{'FAR ABOVE' if r['far_independent'] else 'within'}; a replay's noise worth "
                  f"{r['replay_entries']:.1f} independent entries", flush=True)
            for i, (n_g, per, v) in enumerate(r.get("groups", [])):
                print(f"    group {i:2d}: {n_g:3d} entries, cost per entry {per:7.2f}, replay variance {v:6.2f}")
    ok = [r for r in rows if not r.get("infeasible")]
    if ok:
        print(f"the truth far above its floor: {sum(r['far'] for r in ok)} of {len(ok)} anchors; with independent "
              f"entries of unit noise: {sum(r['far_independent'] for r in ok)} of {len(ok)}")


if __name__ == "__main__":
    main()
