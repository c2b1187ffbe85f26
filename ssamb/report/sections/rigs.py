"""Report section "Close the loop on a real rig's measurements": every rig of config
``closeloop.rigs`` (a device other than the AMB, its recordings), read from
``results/rigs/<rig>/closeloop.json`` and its figures."""
from __future__ import annotations

from ...io import read_json
from ..context import Context
from ..elements import Image, Section, Table

__all__ = ["rigs"]


def _f(x, spec=".4g"):
    return "-" if x is None else format(x, spec)


def _parameters(C: dict) -> list:
    recs = list(C.get("recordings", {}))
    rows = []
    for key, p in C.get("parameters", {}).items():
        per = p.get("per_recording", {})
        agree = C.get("agreement", {}).get(key)
        rows.append([key, _f(p["nominal"]), f"{p['value']:.5g} +- {p['se']:.2g}",
                     f"{100 * p['relative_change']:+.1f} %" if p.get("relative_change") is not None else "-"]
                    + [f"{per[r]['value']:.4g} +- {per[r]['se']:.2g}" if r in per else "not identified" for r in recs]
                    + [f"{agree['max_pair_z']:.2f} ({'agree' if agree['agree'] else 'DISAGREE'})" if agree else "-"])
    out = []
    if rows:
        out.append(Table(["parameter", "published", "combined", "change"] + [f"on {r}" for r in recs]
                         + ["largest pairwise |z|"], rows,
                         caption="Identified parameters (MAP, tolerances as priors): combined (one calibration on "
                                 "all fitting recordings) and per fitting recording; two recordings agree when "
                                 "|z| <= 3"))
    ni = C.get("not_identifiable", {})
    if ni:
        out.append(Table(["parameter", "why the data do not identify it"], [[k, v] for k, v in ni.items()]))
    return out


def _joint(C: dict) -> list:
    """The combined model: every shared parameter of the joint calibration, identified or not."""
    J = C.get("joint_calibration")
    if not J:
        return []
    agree = C.get("calibration_agreement", {})
    recs = list(J.get("recordings", []))
    rows = []
    for q in J.get("parameters", []):
        per = agree.get(q["key"], {}).get("per_recording", {})
        rows.append([q["key"], _f(q["nominal"]), f"{q['value']:.5g} +- {q['se']:.2g}",
                     "yes" if q["identified"] else "no"]
                    + [f"{per[r]['value']:.4g} +- {per[r]['se']:.2g}" if r in per else "-" for r in recs])
    short = (" (stopped short: not converged, its cost far above the noise floor; where such a calibration ends "
             "depends on the estimator's path, so these values and the held-out errors are one draw of a spread: "
             "`python bench/maglev_spread.py` measures it over design seeds)") if J.get("stopped_short") else ""
    cap = (f"The combined model: one calibration on all fitting recordings at once, each with its own session "
           f"parameters, started from {J.get('start')}'s calibration; cost {_f(J.get('cost_over_noise_floor'), '.3g')} "
           f"times its noise floor{short}. Every shared parameter enters the model at its estimate, identified "
           f"or not; beside it each recording's own calibration")
    return [Table(["parameter", "published", "combined", "identified"] + [f"on {r}" for r in recs], rows, caption=cap)]


def _sessions(C: dict) -> list:
    rows = []
    for key, s in C.get("session_parameters", {}).items():
        for part in ("fit", "hold"):
            for rec, p in s.get(part, {}).items():
                se = p.get("se")
                rows.append([key, rec, "fitting" if part == "fit" else "held out (its own first part)",
                             f"{p['value']:.5g}" + (f" +- {se:.2g}" if se is not None else " (not identified)")])
    if not rows:
        return []
    return [Table(["session parameter", "recording", "calibrated on", "value"], rows,
                  caption="Parameters that may change between recordings (closeloop.session): calibrated per "
                          "recording, never combined")]


def _errors(C: dict) -> list:
    rows = []
    for name, h in C.get("holdout", {}).items():
        for c, d in h["channels"].items():
            rows.append([name, c, _f(d["rms_before"]), _f(d["rms_after"]), _f(d["noise_rms"]),
                         "yes" if d["above_noise"] else "no", _f(d["ratio"], ".2f"),
                         f"{h['analysed_s'][0]:.1f}-{h['analysed_s'][1]:.1f} s"])
    b, a = C["error_before"], C["error_after"]
    pooled = [["all held out", c, _f(b[c]["rms"]), _f(a[c]["rms"]), _f(b[c]["noise_rms"]),
               "yes" if b[c]["above_noise"] else "no", _f(a[c].get("ratio_to_before"), ".2f"), ""] for c in b]
    return [Table(["recording", "channel", "rms published", "rms final", "noise floor", "above floor",
                   "final / published", "analysed"], rows + pooled,
                  caption="Held-out recordings: rms error of the published-parameter model and of the final model "
                          "(SI units), the noise floor (the spread of single replays, the recording being one more), "
                          "and whether the published model's error stands above twice it")]


def _effects(C: dict) -> list:
    rows = [[e["name"], ", ".join(f"{k} = {_f(v)}" for k, v in e["params"].items()), ", ".join(e["found_in"]),
             _f(e["holdout_z"], ".2f"), "kept"] for e in C.get("effects", [])]
    rows += [[e["name"], ", ".join(f"{k} = {_f(v)}" for k, v in e["params"].items()), ", ".join(e["found_in"]),
              _f(e["holdout_z"], ".2f"),
              "rejected: " + (e.get("contradicted") or "not significant on the held-out recordings")]
             for e in C.get("effects_rejected", [])]
    out = []
    if rows:
        out.append(Table(["effect", "parameters", "found in", "held-out z", "verdict"], rows,
                         caption=f"Effects found on the fitting recordings, judged on the held-out ones "
                                 f"(kept when z exceeds the one-sided level {C['validation']['alpha_accept']:g})"))
    else:
        out.append("No library effect was found on the fitting recordings.")
    ni = C.get("effects_not_identifiable", {})
    if ni:
        out.append(Table(["effect", "why these data cannot identify it"], [[k, v] for k, v in ni.items()]))
    return out


def _checks(C: dict) -> list:
    rows = []
    for rec, c in C.get("physical_checks", {}).items():
        for name, d in c.get("final", {}).items():
            pub = c.get("published", {}).get(name, {})
            rows.append([rec, name, d.get("summary", ""), pub.get("summary", "")])
    if not rows:
        return []
    return [Table(["recording", "check", "data against the final model", "against the published parameters"], rows,
                  caption="Physical checks: a number computed from the data alone beside what the model predicts")]


def rigs(ctx: Context) -> Section | None:
    """Close the loop on every real rig of the run (None if there is none)."""
    root = ctx.path("rigs")
    dirs = sorted(d for d in root.iterdir() if (d / "closeloop.json").exists()) if root.exists() else []
    if not dirs:
        return None
    sec = Section("7. Close the loop on a real rig's measurements (beyond the paper)").add(
        "The same engine as in the previous section, on measurements a real rig made: the recordings are split "
        "into fitting and held-out ones; each fitting recording is calibrated and searched on its own (its "
        "levitated stretches), the parameters are combined (and their agreement between recordings tested), and "
        "every error below is on recordings the fit never saw.")
    for d in dirs:
        C = read_json(d / "closeloop.json")
        v = C["validation"]
        stops = [r for r, hit in C.get("stops_hit_by_model_only", {}).items() if hit]
        off = [k for k, a in C.get("agreement", {}).items() if not a["agree"]]
        unpaired = [k for k, p in C.get("parameters", {}).items() if len(p.get("per_recording", {})) < 2]
        sec.add(f"### Rig `{d.name}` (device `{C['data']['device']}`)",
                f"Fitted on {', '.join(v['fit_recordings'])}; held out: {', '.join(v['holdout_recordings'])}; "
                f"errors on {v['errors_on']}. "
                + (f"**The final model's replay touches a stop where the data do not** on {', '.join(stops)}. "
                   if stops else "The final model's replays touch no stop the data do not. ")
                + (f"**Recordings disagree** on {', '.join(off)} (more than 3 standard errors apart). " if off else "")
                + (f"**Agreement not established** for {', '.join(unpaired)}: identified on fewer than two fitting "
                   "recordings. " if unpaired else "")
                + f"Residual on the held-out recordings {'not ' if C['unexplained'] else ''}within twice the "
                "noise floor on every channel where the published model stood above it.",
                *_joint(C), *_parameters(C), *_sessions(C), *_errors(C), *_effects(C), *_checks(C))
        for fig in C.get("figures", []):
            sec.add(Image(d / fig))
    return sec
