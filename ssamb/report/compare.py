"""The paper-versus-reproduction table: one row per headline, the paper's value (quoted,
:mod:`ssamb.paper`), ours as median [min-max] over the noise realisations, the ceiling (the fit
no model can exceed), the paper's way, the paper's identification taken literally and the
paper's rig, and why they differ -- each "why" computed from those runs.

Every chain is a *view*: with the noise ensembles (``ensemble.json``) its distribution over the
realisations, before them its realisation 0 (one run's summary). A chain without a number in a
row shows "—"; a chain whose run failed says so once (:func:`failure_notes`), naming its stage.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from ..paper import PAPER
from ..stages.ensemble import OUTCOMES, QUANTITIES, run_quantities
from ..stages.summary import first_failure

__all__ = ["comparison_rows", "comparison_header", "HEADER", "ChainView", "chain_views", "failure_notes", "mover",
           "answer_text", "CHAINS"]

#: chain -> its column title
CHAINS = {"default": "ours", "paper": "the paper's way", "paper_literal": "the literal chain",
          "paper_rig": "the paper's rig"}
HEADER = ["quantity", "paper", "ours", "the paper's way", "why (computed)"]


def _f(v, d=4, unit=""):
    if v is None:
        return "none"
    if isinstance(v, float):
        return f"{v:.{d}g}{unit}"
    return f"{v}{unit}"


def _get(d: Mapping | None, *keys) -> Any:
    for k in keys:
        if not isinstance(d, Mapping):
            return None
        d = d.get(k)
    return d


@dataclass
class ChainView:
    """One chain's numbers for the table: per quantity a distribution (``K``, ``median``, ``min``,
    ``max``; ``K = 1`` for a single run), per outcome the fraction, its failure and μ-peak cause."""

    name: str
    quantities: dict
    fractions: dict
    realisations: int
    failure: dict | None = None
    failed_runs: int = 0
    cause: str | None = None
    extra: dict = field(default_factory=dict)

    def q(self, key: str) -> Mapping:
        return self.quantities.get(key) or {"K": 0}

    def cell(self, key: str, d: int = 4, unit: str = "", scale: float = 1.0) -> str:
        """``median [min-max] (k/K)`` over the realisations, the value of a single run, or "—"."""
        q = self.q(key)
        if not q.get("K"):
            return "—"
        med, lo, hi = (q[k] * scale for k in ("median", "min", "max"))
        if self.realisations <= 1:
            return _f(med, d, unit)
        tail = f" ({q['K']}/{self.realisations})" if q["K"] < self.realisations else ""
        return f"{_f(med, d, unit)} [{_f(lo, d)}–{_f(hi, d)}]{tail}"

    def fraction(self, key: str) -> str:
        f = self.fractions.get(key) or {}
        if not f.get("K"):
            return "—"
        if self.realisations <= 1:
            return "yes" if f["count"] else "no"
        return f"{f['count']}/{f['K']}"


def _single(name: str, s: Mapping) -> ChainView:
    q = run_quantities(s)
    quant = {k: ({"K": 1, "median": q[k], "min": q[k], "max": q[k]} if q[k] is not None else {"K": 0})
             for k in QUANTITIES}
    fr = {k: ({"K": 1, "count": int(bool(q[k]))} if q[k] is not None else {"K": 0}) for k in OUTCOMES}
    cause = (_get(s, "mu", "selfsensing", "cause") or {}).get("sentence")
    fail = first_failure(s.get("failed"))
    return ChainView(name, quant, fr, 1, fail, int(fail is not None), cause)


def _from_ensemble(name: str, c: Mapping) -> ChainView:
    fails = [f for f in (c.get("failures") or {}).values() if f]
    sentences = c.get("mu_peak_sentences") or {}
    med_run = _median_run(c)
    cause = sentences.get(med_run) if med_run else None
    return ChainView(name, c["quantities"], c["fractions"], c["realisations"], fails[0] if fails else None,
                     len(fails), cause, {"causes": c.get("mu_peak_causes") or {}})


def _median_run(c: Mapping) -> str | None:
    """The realisation whose μ peak frequency is the median one (its cause sentence is quoted)."""
    q = c["quantities"]["mu_peak_hz"]
    if not q.get("K"):
        return None
    pairs = sorted(zip(q["values"], q["runs"]))
    return pairs[len(pairs) // 2][1]


def chain_views(S: Mapping, ensemble: Mapping | None = None, summaries: Mapping[str, Mapping] | None = None) -> dict:
    """chain -> :class:`ChainView`: from the ensembles when they exist, else from realisation 0
    (``S`` is the default run's summary; ``summaries`` the scenario runs' that exist). A single
    run whose validation failed but whose sweep is the default run's simulation (same config
    hash) shows the default run's nonlinear numbers: they are the same simulation's."""
    from ..stages.ensemble import fill_shared_nonlinear

    views = {}
    ens = (ensemble or {}).get("chains") or {}
    singles = {"default": S, **(summaries or {})}
    pw = S.get("paper_way")
    if singles.get("paper") is None and pw:  # the paper's way as the default run's summary holds it
        singles["paper"] = {**pw, "details": {"assembly": {"stable": pw.get("stable")}}}
    for name in CHAINS:
        if name in ens:
            views[name] = _from_ensemble(name, ens[name])
        elif singles.get(name) is not None:
            views[name] = _single(name, fill_shared_nonlinear(singles[name], [S]))
    return views


def failure_notes(views: Mapping[str, ChainView]) -> list[str]:
    """One sentence per chain with a failed run: the stage and the reason (once)."""
    out = []
    for name, v in views.items():
        if v.failure is None:
            continue
        where = "" if v.realisations <= 1 else f" in {v.failed_runs} of {v.realisations} realisations (first: "
        out.append(f"{CHAINS[name][0].upper() + CHAINS[name][1:]}: stage `{v.failure['stage']}` failed{where}"
                   f"{v.failure['reason']}{')' if where else ''}; its rows show what the other stages gave.")
    return out


# ------------------------------------------------------------------------------ study answers
def mover(study: Mapping | None, key: str, unit: str = "", d: int = 3) -> str:
    """'moved most by <variant> (baseline -> value)' for a headline quantity of the study -- only
    beyond the noise band when the study carries one (``study['noise']``) -- or a note that the
    study has not run."""
    if not study:
        return "Which assumption moves it: run `snakemake --cores 2 study`."
    var = study["variants"]
    base = var.get(study["baseline"], {}).get(key)
    band = (_get(study, "noise", key) or {})
    cands = [(n, v[key]) for n, v in var.items() if n != study["baseline"] and v.get(key) is not None]
    if base is None or not cands:
        return "The study has no value for it."
    if band.get("lo") is not None:
        outside = [(n, v) for n, v in cands if not band["lo"] <= v <= band["hi"]]
        if not outside:
            return (f"No study variant moves it beyond the noise ({_f(band['lo'], d, unit)} to "
                    f"{_f(band['hi'], d, unit)} around the baseline).")
        cands = outside
    name, val = max(cands, key=lambda nv: abs(nv[1] - base))
    return f"Moved most by study variant `{name}` ({_f(base, d, unit)} -> {_f(val, d, unit)})."


def answer_text(study: Mapping, answer: str) -> str:
    """What a study answer asks of a variant, with the criteria of ``study.json``."""
    crit = study["criteria"]
    return {"delevitation": "make the nonlinear model delevitate in the sweep while the LTI models do not",
            "mu_peak_near_2hz": f"put the self-sensing μ peak within a factor {crit['mu_peak_factor']:g} of the "
                                f"paper's {PAPER['mu_peak_hz'][0]:g} Hz",
            "fit_y_near_paper": f"give a y fit within {crit['fit_y_points']:g} points of the paper's "
                                f"{PAPER['fit_y_pct'][0]:g} %"}[answer]


def _which(study: Mapping | None, answer: str) -> str:
    if not study:
        return ""
    names = study["answers"][answer]
    return f" Variants that {answer_text(study, answer)}: " + (", ".join(f"`{n}`" for n in names) or "none") + "."


def _reproduced(ensemble: Mapping | None, key: str) -> str:
    """Which chains reproduce a headline within their ensemble spread (ensemble.json)."""
    if not ensemble:
        return " Whether a run reproduces it within the noise: `snakemake --cores 2 ensemble`."
    r = ensemble["reproduces"][key]
    names = [CHAINS.get(c, c) for c in r["chains"]]
    return (f" Reproduced within its ensemble spread ({r['target']}) by: " + (", ".join(names) or "no chain") + ".")


# ------------------------------------------------------------------------------------ rows
def comparison_header(views: Mapping[str, ChainView], ceiling: bool) -> list[str]:
    """``quantity, paper, <chains>, [ceiling], why`` for the chains present."""
    cols = ["quantity", "paper", CHAINS["default"] + (" (median [min–max])" if views["default"].realisations > 1
                                                      else "")]
    if ceiling:
        cols.append("ceiling (nonlinear vs nonlinear)")
    return cols + [CHAINS[n] for n in CHAINS if n != "default" and n in views] + ["why (computed)"]


def _row(views, ceiling, quantity: str, paper: str, key: str | None, why: str, d: int = 4, unit: str = "",
         scale: float = 1.0, fraction: str | None = None, ceil: str | None = None) -> list:
    def cell(v: ChainView) -> str:
        if fraction is not None:
            return v.fraction(fraction)
        return v.cell(key, d, unit, scale) if key else "—"

    row = [quantity, paper, cell(views["default"])]
    if ceiling:
        row.append(ceil if ceil is not None else "")
    return row + [cell(views[n]) for n in CHAINS if n != "default" and n in views] + [why]


def _ceiling_cell(S: Mapping, views: Mapping[str, ChainView], key: str) -> str:
    q = views["default"].q(key).get("ceiling") or (S.get("ceiling") or {}).get(key)
    if not q or not q.get("K"):
        return "—"
    return f"{q['median']:.4g} [{q['min']:.4g}–{q['max']:.4g}]"


def _fit_why(S, views, study, ensemble, key: str, axis: str) -> str:
    ours = views["default"].q(key)
    c = views["default"].q(key).get("ceiling") or (S.get("ceiling") or {}).get(key)
    paper = PAPER[key][0]
    parts = []
    if c and c.get("K"):
        where = ("above the whole range" if paper > c["max"] else "below the whole range" if paper < c["min"]
                 else "inside the range")
        parts.append(f"The ceiling (one nonlinear run against the mean of {c['K'] - 1} others with only the converter "
                     f"noise drawn anew) is {c['median']:.4g} % [{c['min']:.4g}–{c['max']:.4g}]: no LTI model can fit "
                     f"the {axis} axis better; the paper's {paper:g} % is {where} of it.")
        if ours.get("K"):
            parts.append(f"Our median is {c['median'] - ours['median']:.3g} points below the ceiling's.")
    P = views.get("paper")
    if P is not None:
        st = P.fractions.get("stable") or {}
        if st.get("K"):
            parts.append(f"The paper's way gives a stable loop in {st['count']} of {st['K']} realisation(s).")
    parts.append(mover(study, key, " %"))
    if key == "fit_y_pct":
        parts.append(_which(study, "fit_y_near_paper").strip())
        parts.append(_reproduced(ensemble, "fit_y").strip())
    return " ".join(p for p in parts if p)


def _fit_rows(S, views, ceiling, study, ensemble) -> list:
    return [_row(views, ceiling, "closed-loop LTI fit, x (Fig. 4)", f"{PAPER['fit_x_pct'][0]} %", "fit_x_pct",
                 _fit_why(S, views, study, ensemble, "fit_x_pct", "x"), unit=" %",
                 ceil=_ceiling_cell(S, views, "fit_x_pct")),
            _row(views, ceiling, "closed-loop LTI fit, y (Fig. 4)", f"{PAPER['fit_y_pct'][0]} %", "fit_y_pct",
                 _fit_why(S, views, study, ensemble, "fit_y_pct", "y"), unit=" %",
                 ceil=_ceiling_cell(S, views, "fit_y_pct")),
            _row(views, ceiling, "assembled LTI loop stable", "yes (its Fig. 4 fits exist)", None,
                 "Spectral radius of the assembled discrete loop below 1; the paper's structures need the selection "
                 "by the assembled loop (config identification.selection), and the literal chain's offset-free "
                 "models can move the loop's poles.", fraction="stable")]


def _order_row(S, views, ceiling) -> list:
    orders = "/".join(str(PAPER[f"order_{k}"][0]) for k in ("plant", "amplifier", "selfsensing"))
    ours = "/".join(_f(S["orders"].get(k)) for k in ("plant", "amplifier", "selfsensing"))
    row = ["model orders plant/amplifier/self-sensing", orders, ours]
    if ceiling:
        row.append("")
    return row + [ours for n in CHAINS if n != "default" and n in views] + [
        "Configured (identification.<subsystem>.order) in every chain; the order scan in report section 2 is "
        "the evidence."]


def _mu_why(views, study, ensemble) -> str:
    parts = []
    for n, v in views.items():
        if v.cause:
            parts.append(f"{CHAINS[n][0].upper() + CHAINS[n][1:]}: {v.cause}"
                         + (f" (causes over the realisations: {_counts(v.extra['causes'])})"
                            if v.extra.get("causes") and v.realisations > 1 else "") + ".")
    parts.append(mover(study, "mu_peak_hz", " Hz") + _which(study, "mu_peak_near_2hz"))
    parts.append(_reproduced(ensemble, "mu_peak").strip())
    return " ".join(parts)


def _counts(c: Mapping) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(c.items(), key=lambda kv: -kv[1]))


def _mu_rows(S, views, ceiling, study, ensemble) -> list:
    return [_row(views, ceiling, "weight fit, largest deviation from the envelope",
                 f"<= {PAPER['weight_fit_max_db'][0]} dB",
                 "weight_fit_max_db", "Every chain's fit is held to the same tolerance (config uncertainty.tol_db).",
                 d=3, unit=" dB"),
            _row(views, ceiling, "weight scale factor for a μ peak of 1 (self-sensing)",
                 _f(PAPER["mu_scale_for_unity"][0]), "mu_scale_for_unity",
                 "The scale is 1/peak of μ with the measured weight; the paper's 0.0012 means a μ peak of "
                 f"{1 / PAPER['mu_scale_for_unity'][0]:.0f}. " + mover(study, "mu_scale_for_unity"), d=3),
            _row(views, ceiling, "μ peak frequency (self-sensing)", f"~{PAPER['mu_peak_hz'][0]:g} Hz", "mu_peak_hz",
                 _mu_why(views, study, ensemble), d=3, unit=" Hz")]


def _sweep_rows(S, views, ceiling, study, ensemble) -> list:
    sw = _get(S, "details", "validation", "sweep") or {}
    band = PAPER["sweep_band_hz"][0]
    amp = PAPER["sweep_amplitude_m"][0] * 1e6
    ours = (f"{sw['amplitude_m'] * 1e6:.3g} µm, {sw['f_start_hz']:g}-{sw['f_stop_hz']:g} Hz in "
            f"{sw['sweep_duration_s']:g} s ({sw.get('law', 'linear')})") if sw else "none"
    rig = views.get("paper_rig")
    rig_why = ""
    if rig is not None:
        nl = rig.q("critical_nonlinear_um")
        rig_why = (f" The paper's rig (50 turns per electromagnet, a shared weight, a slower sweep: config "
                   f"scenarios.paper_rig) puts the nonlinear model's critical amplitude at "
                   f"{rig.cell('critical_nonlinear_um', 3, ' µm')}, the nominal LTI model's at "
                   f"{rig.cell('critical_nominal_um', 3, ' µm')}.") if nl.get("K") else ""
    return [
        ["sweep signal (section 6)", f"{amp:.3g} µm, {band[0]:g}-{band[1]:g} Hz, duration not stated", ours]
        + ([""] if ceiling else []) + ["as ours" if n != "paper_rig" else "0.5 s sweep (config)"
                                       for n in CHAINS if n != "default" and n in views]
        + ["The paper gives amplitude and band, not the rate; the study varies the duration and the law."],
        _row(views, ceiling, "nonlinear model delevitates in the sweep", "yes", None,
             "Fraction of the realisations (a yes/no at one amplitude is a knife edge: the critical amplitudes "
             "below are the comparison).", fraction="delevitates_nonlinear"),
        _row(views, ceiling, "delevitation time, nonlinear", f"just after {PAPER['delevitation_nonlinear_s'][0]} s",
             "delevitation_nonlinear_s", "Over the realisations that delevitate." + rig_why
             + " " + _reproduced(ensemble, "delevitation").strip() + _which(study, "delevitation"), d=3, unit=" s"),
        _row(views, ceiling, "critical sweep amplitude, nonlinear", f"< {amp:.3g} µm (it delevitated)",
             "critical_nonlinear_um", "Bisection over nonlinear simulations of the sweep (config validation). "
             + mover(study, "critical_nonlinear_um", " µm"), d=3, unit=" µm"),
        _row(views, ceiling, "nominal LTI model delevitates", "no", None,
             "Fraction of the realisations.", fraction="delevitates_nominal"),
        _row(views, ceiling, "critical sweep amplitude, nominal LTI", f"> {amp:.3g} µm (it held)",
             "critical_nominal_um", "Exact for an LTI model: the clearance over the largest response per unit "
             "amplitude. " + mover(study, "critical_lti_um", " µm"), d=3, unit=" µm"),
        _row(views, ceiling, "an augmented LTI model delevitates", "no", None,
             "Δ = +1, −1 and an all-pass, each with the measured weight; fraction of the realisations.",
             fraction="delevitates_augmented"),
        _row(views, ceiling, "critical sweep amplitude, augmented LTI (smallest over Δ)", f"> {amp:.3g} µm (it held)",
             "critical_augmented_um", "Exact, as for the nominal model.", d=3, unit=" µm"),
    ]


def comparison_rows(S: Mapping, study: Mapping | None = None, ensemble: Mapping | None = None,
                    summaries: Mapping[str, Mapping] | None = None) -> tuple[list[str], list[list]]:
    """Header and rows of the first table from the default run's summary ``S``, the study and
    the ensembles when they have run, and the scenario runs' summaries (``summaries``: chain ->
    ``summary.json`` of its realisation 0, for the chains the ensembles do not have yet)."""
    views = chain_views(S, ensemble, summaries)
    ceiling = bool(S.get("ceiling")) or bool(views["default"].q("fit_y_pct").get("ceiling"))
    iso = S["iso14839_peak_sensitivity"]
    iso_row = ["ISO 14839-3 peak sensitivity x / y", "not reported", f"{_f(iso['x'], 3)} / {_f(iso['y'], 3)}"]
    if ceiling:
        iso_row.append("")
    iso_row += ["—" for n in CHAINS if n != "default" and n in views]
    iso_row.append("The baseline the paper argues against, from the same closed-loop model (default run).")
    rows = (_fit_rows(S, views, ceiling, study, ensemble) + [_order_row(S, views, ceiling)]
            + _mu_rows(S, views, ceiling, study, ensemble) + _sweep_rows(S, views, ceiling, study, ensemble)
            + [iso_row])
    return comparison_header(views, ceiling), rows
