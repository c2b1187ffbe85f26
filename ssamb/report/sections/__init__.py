"""The report sections, in order: each is a function ``section(ctx) -> Section`` that reads the
run's ``summary.json``, stage files and config (:class:`ssamb.report.context.Context`) and
returns text, tables and figures (:mod:`ssamb.report.elements`). The notebook only calls them.
"""
from __future__ import annotations

from .analysis import identification, mu, uncertainty, validation
from .closeloop import closeloop
from .overview import comparison, overview, parameters, provenance, simulation
from .study import paper_way, sensitivity

__all__ = ["ORDER", "overview", "comparison", "parameters", "simulation", "identification", "uncertainty",
           "mu", "validation", "paper_way", "sensitivity", "closeloop", "provenance"]

#: names of the section functions in report order
ORDER = ("overview", "comparison", "parameters", "simulation", "identification", "uncertainty", "mu",
         "validation", "paper_way", "sensitivity", "closeloop", "provenance")
