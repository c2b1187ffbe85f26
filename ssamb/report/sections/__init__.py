"""The report sections, in order: each is a function ``section(ctx) -> Section`` that reads the
run's ``summary.json``, stage files and config (:class:`ssamb.report.context.Context`) and
returns text, tables and figures (:mod:`ssamb.report.elements`). The notebook only calls them.

The first page is what a reviewer of the paper reads first: the paper against this run (the
table) and the paper's Figs. 4, 7, 8 and 9 as this run made them. The chain's sections follow;
the configuration closes the report as a folded appendix.
"""
from __future__ import annotations

from .analysis import identification, mu, uncertainty, validation
from .closeloop import closeloop
from .ensemble import ensemble
from .overview import comparison, figures, overview, parameters, provenance, simulation
from .rigs import rigs
from .study import paper_way, sensitivity

__all__ = ["ORDER", "overview", "comparison", "figures", "parameters", "simulation", "identification",
           "uncertainty", "mu", "validation", "paper_way", "ensemble", "sensitivity", "closeloop", "rigs", "provenance"]

#: names of the section functions in report order
ORDER = ("overview", "comparison", "figures", "simulation", "identification", "uncertainty", "mu",
         "validation", "paper_way", "ensemble", "sensitivity", "closeloop", "rigs", "provenance", "parameters")
