"""Report section: the noise ensembles (``snakemake --cores 2 ensemble``): every chain's headline
numbers over its noise realisations, the ceilings, the yes/no fractions, and which run
reproduces each of the paper's three headlines -- or, computed, why none does."""
from __future__ import annotations

from ...stages.ensemble import OUTCOMES, QUANTITIES
from ..compare import CHAINS
from ..context import Context
from ..elements import Image, Section, Table

__all__ = ["ensemble"]

#: headline -> its title in the section
HEADLINES = {"fit_y": "The y fit near 50.76 %",
             "mu_peak": "A μ peak near 2 Hz with a weight scale near 0.0012",
             "delevitation": "Nonlinear delevitation just after 0.18 s while the LTI models hold"}


def _cell(q) -> str:
    if not q.get("K"):
        return "—"
    return f"{q['median']:.4g} [{q['min']:.4g}–{q['max']:.4g}]"


def ensemble(ctx: Context) -> Section:
    """The ensembles' tables, figure and the three headlines' verdicts (ensemble.json)."""
    sec = Section("Noise ensembles").add(
        "Each chain (ours, the paper's way, the literal chain, the paper's rig) repeated over independent noise "
        "realisations: the master seed moved by k draws the converter noise, the excitation phases and the "
        "calibration noise anew (config `ensemble`); every stage of every realisation is its own job. A number "
        "that needs a stable assembled loop is taken over the stable realisations only (k/K).")
    E = ctx.ensemble
    if E is None:
        return sec.add("Not in this report: `snakemake --cores 2 ensemble` runs them; every report built after it "
                       "holds them.")
    chains = E["chains"]
    names = [n for n in CHAINS if n in chains] + [n for n in chains if n not in CHAINS]
    title = {n: CHAINS.get(n, n) for n in names}
    rows = []
    for key, (label, unit, *_rest) in QUANTITIES.items():
        row = [f"{label} ({unit})"]
        for n in names:
            q = chains[n]["quantities"][key]
            row.append(_cell(q) + (f" ({q['K']}/{chains[n]['realisations']})"
                                   if q.get("K") and q["K"] < chains[n]["realisations"] else ""))
        c = chains["default"]["quantities"][key].get("ceiling") if "default" in chains else None
        row.append(_cell(c) if c else "")
        rows.append(row)
    frac = [[label] + [f"{chains[n]['fractions'][k]['count']}/{chains[n]['fractions'][k]['K']}" for n in names]
            for k, (label, _) in OUTCOMES.items()]
    fails = [[title[n], f"{len(chains[n]['failures'])} of {chains[n]['realisations']}",
              "; ".join(sorted({f"{f['stage']}: {f['reason']}" for f in chains[n]["failures"].values() if f}))]
             for n in names if chains[n]["failures"]]
    verdicts = [[HEADLINES[k], ", ".join(title.get(c, c) for c in v["chains"]) or "none", v["target"],
                 v.get("why", "")] for k, v in E["reproduces"].items()]
    sec.add(Table(["quantity"] + [f"{title[n]} (K = {chains[n]['realisations']})" for n in names]
                  + ["ceiling (nonlinear vs nonlinear)"], rows,
                  caption="Median [min–max] over the realisations; the ceiling is one nonlinear run against the "
                          "mean of the others with only the converter noise drawn anew"),
            Table(["outcome"] + [title[n] for n in names], frac, caption="Yes/no outcomes: realisations where it "
                                                                         "holds / realisations where it is defined"),
            Image(ctx.path("ensemble", "ensemble.png")))
    if fails:
        sec.add(Table(["chain", "realisations failed", "the stage that failed and why"], fails,
                      caption="Failed realisations, each named once by the stage the others follow from"))
    return sec.add(
        "**The paper's three headlines against the ensembles** (each verdict computed from the numbers above, with "
        "config `ensemble.criteria` for how precisely the paper states each value):",
        Table(["headline", "reproduced within its ensemble spread by", "criterion", "why (computed)"], verdicts))
