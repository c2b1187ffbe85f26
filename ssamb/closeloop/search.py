r"""Greedy search: add library effects while the held-out error drops significantly.

Round :math:`r` (base model = nominal model + the effects accepted so far):

1. features of the base residual on the fitting part, evidence of every library effect,
   candidates ranked by evidence (:mod:`ssamb.closeloop.signatures`); when no signature is
   significant but the held-out residual is not noise, each library effect that needs no hint
   from a signature is a candidate (a signature can drown in a noisy estimate while the
   time-domain residual is plain; pairs are not tried then);
2. the best-ranked ``candidates_per_round`` are fitted by simulation on the fitting part
   (:func:`ssamb.closeloop.fit.fit_effect`) and simulated over the whole record;
3. a candidate passes when, on the held-out part, the improvement test is significant
   (:math:`z > z_{1-\alpha}`), it explains at least ``min_explained`` of the residual excess
   of the views that stood above the noise, it makes no view worse, the BIC drops, and its
   own signature is gone from the residual (its claim statistic falls below the evidence
   threshold or to 1 % of its value: an effect that explains only part of a feature, like an
   unbalance fitted to a force in one axis, fails);
4. when no candidate passes: a candidate that improved the held-out error but failed only on
   side effects is refitted together with the effects already accepted (those were fitted
   without it and are biased by it); then the leading pairs of smooth candidates are fitted
   jointly (two effects can hide each other: each biases the other's fit alone);
5. the passing candidate (or pair) with the largest held-out improvement is accepted, and all
   accepted effects are polished (each refitted once with the others present).

The search stops when no candidate passes, ``max_effects`` are in, or the held-out residual is
consistent with noise (:func:`ssamb.closeloop.residual.consistency`).
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .data import views
from .fit import fit_effect, holdout_score
from .models import combine, effect_model, report_entries, restart, split_fit
from .residual import compute_features, consistency
from .signatures import claim_stat, evidence_all, rank

__all__ = ["SearchResult", "greedy_search"]


@dataclass
class SearchResult:
    """Outcome of the greedy search.

    Attributes
    ----------
    accepted : list of dict
        Per accepted effect: the fit, the held-out score, the evidence, the report entries.
    rounds : list of dict
        Per round: the evidence table and every candidate tried, with its verdict.
    effects : list
        Effect specs of the final model.
    final : dict
        Channels of the final model over the whole record.
    """

    accepted: list = field(default_factory=list)
    rounds: list = field(default_factory=list)
    effects: list = field(default_factory=list)
    final: dict = field(default_factory=dict)
    final_features: object = None
    nominal_features: object = None
    consistent: bool = False
    failures: list = field(default_factory=list)


def _log(progress: bool, msg: str) -> None:
    if progress:
        sys.stderr.write(f"closeloop: {msg}\n")
        sys.stderr.flush()


def _significant(fr) -> np.ndarray:
    """Parameters that differ from zero: by 3 standard errors, and by 1e-3 of their natural
    scale (the finite-difference step; standard errors of a long record can be far below any
    practical difference)."""
    return (np.abs(fr.theta) > 3 * fr.se) & (np.abs(fr.theta) > 1e-3 * fr.model.step)


def _refit_accepted(acc_fits: list, extra_effects: list, replay, meas_v, split, sigma, settings) -> list:
    """Refit each accepted effect (one pass) with the others and ``extra_effects`` present."""
    fits = list(acc_fits)
    for j, f in enumerate(fits):
        others = [e for k, g in enumerate(fits) if k != j for e in g.effects] + list(extra_effects)
        base = views(replay.run(others + f.effects, n=split.fit.stop))
        new = fit_effect(replay, others, restart(f.model, f.theta), meas_v, base, split.fit, sigma,
                         settings.max_gn_iterations)
        if new.cost <= new.cost0:
            new.cost0 = f.cost0
            fits[j] = new
    return fits


def _polish(out: SearchResult, replay, meas_v, split, sigma, settings, progress):
    """Refit each accepted effect with the others fixed at their current values (one pass).

    An effect fitted before the next one was found is biased by it; one coordinate pass removes
    most of that bias. Returns the new base model (channels, views)."""
    for j, acc in enumerate(out.accepted):
        others = [e for k, a in enumerate(out.accepted) if k != j for e in a["fit"].effects]
        fr_old = acc["fit"]
        base_ch = replay.run(others + fr_old.effects, n=split.fit.stop)
        model = restart(fr_old.model, fr_old.theta)
        fr = fit_effect(replay, others, model, meas_v, views(base_ch), split.fit, sigma, settings.max_gn_iterations)
        if fr.cost <= fr_old.cost * (1 + 1e-9) or fr.cost < fr.cost0:
            fr.cost0 = fr_old.cost0
            sig = _significant(fr)
            acc["fit"] = fr
            acc["entries"] = report_entries(fr.model, fr.theta, fr.se, sig)
            _log(progress, f"  polish {acc['name']}: {dict(zip(fr.model.params, fr.theta.tolist()))} ({fr.sims} sims)")
    out.effects = [e for a in out.accepted for e in a["fit"].effects]
    final = replay.run(out.effects)
    out.accepted[-1]["model"] = final
    return final, views(final)


def greedy_search(rec, split, replay, nominal: dict, fit_frame, hold_frame, settings, progress: bool = False) -> SearchResult:
    """Run the greedy search (see module docstring)."""
    meas_v = views(rec.channels)
    base_ch = nominal
    base_v = views(base_ch)
    out = SearchResult()
    z_crit = float(stats.norm.isf(settings.alpha_accept))
    claim_crit = float(stats.chi2.isf(settings.alpha_evidence, 2))
    rejected: dict[str, int] = {}
    # a candidate whose model touches the backup bearing is implausible unless the measured
    # rotor did too (radial measured position within 5 % of the clearance)
    clearance = float(replay.cfg["table1"]["backup_clearance_m"])
    measured_contact = bool(np.max(np.hypot(rec.channels["x_meas"], rec.channels["y_meas"])) >= 0.95 * clearance)
    for rnd in range(settings.max_effects + 1):
        t0 = time.perf_counter()
        ft = compute_features(rec, fit_frame, meas_v, base_v, settings)
        ev = evidence_all(ft, settings.alpha_evidence)
        order = [n for n in rank(ev) if n not in {a["name"] for a in out.accepted} and rejected.get(n, 0) < 2]
        info = {"round": rnd, "evidence": {n: e.to_json() for n, e in ev.items()}, "ranking": rank(ev),
                "candidates": []}
        out.rounds.append(info)
        hold_ft = compute_features(rec, hold_frame, meas_v, base_v, settings, rec.channels, base_ch)
        ok, fails = consistency(hold_ft, settings.alpha_noise)
        out.consistent, out.failures, out.final_features = ok, fails, hold_ft
        if rnd == 0:
            out.nominal_features = hold_ft
        _log(progress, f"round {rnd}: evidence ranking {rank(ev) or 'none'}; held-out residual "
                       f"{'consistent with noise' if ok else 'not consistent with noise'} ({time.perf_counter() - t0:.1f} s)")
        if not order and not ok and rnd < settings.max_effects:
            # no signature stands out, yet the held-out residual is not noise (a signature can
            # drown, e.g. a y-sensor delay under current pulses, whose ratio estimate is
            # imprecise): fit the library effects that need no hint from a signature (not the
            # unbalance, whose speed comes from a line), most evidence first, judged by the
            # same held-out criteria
            taken = {a["name"] for a in out.accepted}
            order = [n for n in sorted(ev, key=lambda n: ev[n].log10_p)
                     if n != "unbalance" and n not in taken and rejected.get(n, 0) == 0]
            info["fallback"] = bool(order)
            _log(progress, f"round {rnd}: no significant signature; fitting each of {order}")
        if (ok and rnd > 0) or not order or rnd == settings.max_effects:
            break
        sigma = ft.sigma

        def attempt(names, repolish=False):
            """Fit ``names`` jointly (one effect, or a pair) and judge the result.

            With ``repolish`` the effects already accepted are refitted with the candidate
            present (they were fitted without it, and are biased by it), then the candidate again.
            """
            t1 = time.perf_counter()
            models = [effect_model(n, ev[n].hints, rec.excited_axes) for n in names]
            model = combine(models)
            fr = fit_effect(replay, out.effects, model, meas_v, base_v, split.fit, sigma, settings.max_gn_iterations)
            acc_fits = [a["fit"] for a in out.accepted]
            if repolish and acc_fits:
                acc_fits = _refit_accepted(acc_fits, fr.effects, replay, meas_v, split, sigma, settings)
                acc_eff = [e for f in acc_fits for e in f.effects]
                pre = views(replay.run(acc_eff, n=split.fit.stop))
                fr2 = fit_effect(replay, acc_eff, restart(model, fr.theta), meas_v, pre, split.fit, sigma,
                                 settings.max_gn_iterations)
                fr2.sims += fr.sims
                fr2.cost0 = fr.cost0
                fr = fr2
            acc_eff = [e for f in acc_fits for e in f.effects]
            cand_ch = replay.run(acc_eff + fr.effects)
            cand_v = views(cand_ch)
            hs = holdout_score(meas_v, base_v, cand_v, split.hold, sigma)
            ft_after = compute_features(rec, fit_frame, meas_v, cand_v, settings)
            reasons = []
            if hs["z"] <= z_crit:
                reasons.append(f"held-out improvement not significant (z = {hs['z']:.2f} <= {z_crit:.2f})")
            if hs["explained"] < settings.min_explained * len(names):
                reasons.append(f"explains {100 * hs['explained']:.0f} % of the residual excess "
                               f"(< {100 * settings.min_explained * len(names):.0f} %)")
            if hs["views_worse"]:
                reasons.append(f"makes {', '.join(hs['views_worse'])} worse")
            if fr.delta_bic >= 0:
                reasons.append(f"BIC does not drop ({fr.delta_bic:.1f})")
            claims = {}
            for n in names:
                c_before = claim_stat(n, ft, ev[n].hints, fit_frame.df_hz)
                c_after = claim_stat(n, ft_after, ev[n].hints, fit_frame.df_hz)
                claims[n] = (c_before, c_after)
                if c_after > max(claim_crit, 0.01 * c_before):
                    reasons.append(f"the signature of {n} remains after the fit (claim chi2 {c_before:.3g} -> {c_after:.3g})")
            if cand_ch.get("delevitated") and not measured_contact:
                reasons.append("the model with it delevitates (the measured rotor does not)")
            entry = {"name": "+".join(names) + (" (accepted effects refitted)" if repolish else ""),
                     "theta": dict(zip(fr.model.params, fr.theta.tolist())),
                     "se": dict(zip(fr.model.params, fr.se.tolist())), "sims": fr.sims, "iterations": fr.iterations,
                     "fit_cost_ratio": fr.cost / fr.cost0 if fr.cost0 > 0 else 1.0, "delta_bic": fr.delta_bic,
                     "holdout_z": hs["z"], "explained": hs["explained"], "views_worse": hs["views_worse"],
                     "claims": claims, "passed": not reasons, "reasons": reasons}
            info["candidates"].append(entry)
            _log(progress, f"  {entry['name']}: {entry['theta']} -> held-out z {hs['z']:.1f}, explained "
                           f"{100 * hs['explained']:.0f} %, {'passes' if not reasons else '; '.join(reasons)} "
                           f"({fr.sims} sims, {time.perf_counter() - t1:.1f} s)")
            if reasons:
                return None, reasons
            return (hs["delta_sse"], names, fr, models, cand_ch, cand_v, hs, acc_fits), []

        results = []
        retry = []
        fallback = bool(info.get("fallback"))
        for name in (order if fallback else order[: settings.candidates_per_round]):
            r, why = attempt([name])
            if r is not None:
                results.append(r)
            else:
                rejected[name] = rejected.get(name, 0) + 1
                # a significant improvement that fails only on side effects may be the accepted
                # effects' bias: retry with them refitted
                if out.accepted and all(w.startswith(("makes", "the signature")) for w in why):
                    retry.append(name)
        if not results:
            for name in retry:
                r, _ = attempt([name], repolish=True)
                if r is not None:
                    results.append(r)
        if not results and len(order) >= 2 and not fallback:
            # no single effect explains its signature: two effects may hide each other (each
            # biases the other's fit); fit the leading pairs jointly
            smooth = [n for n in order[: settings.candidates_per_round]
                      if effect_model(n, ev[n].hints, rec.excited_axes).smooth]
            for i in range(len(smooth)):
                for j in range(i + 1, len(smooth)):
                    r, _ = attempt([smooth[i], smooth[j]])
                    if r is not None:
                        results.append(r)
        if not results:
            break
        results.sort(key=lambda x: -x[0])
        _, names, fr, models, cand_ch, cand_v, hs, acc_fits = results[0]
        for a, f in zip(out.accepted, acc_fits):
            if f is not a["fit"]:
                a["fit"] = f
                a["entries"] = report_entries(f.model, f.theta, f.se, _significant(f))
        out.effects = [e for a in out.accepted for e in a["fit"].effects]
        parts = split_fit(fr, models)
        for k, (n, frk) in enumerate(zip(names, parts)):
            sig = _significant(frk)
            model_ch = cand_ch if k == len(names) - 1 else replay.run(out.effects + [e for f in parts[:k + 1] for e in f.effects])
            out.accepted.append({"name": n, "fit": frk, "holdout": hs, "evidence": ev[n],
                                 "entries": report_entries(frk.model, frk.theta, frk.se, sig), "round": rnd,
                                 "model": model_ch})
        out.effects = out.effects + fr.effects
        base_ch, base_v = cand_ch, cand_v
        if len(out.accepted) > 1 and len(names) == 1:
            base_ch, base_v = _polish(out, replay, meas_v, split, sigma, settings, progress)
    out.final = base_ch
    return out
