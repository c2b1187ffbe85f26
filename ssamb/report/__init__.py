"""The HTML report: a notebook built from ``results/`` whose cells call the section functions
(:mod:`ssamb.report.sections`), executed and rendered with nbconvert (:func:`build_report`)."""
from .build import build_report, make_notebook, render_notebook

__all__ = ["build_report", "make_notebook", "render_notebook"]
