"""The HTML report: ``summary.json`` from the stage outputs, and a notebook built from
``results/``, executed and rendered with nbconvert (:func:`build_report`)."""
from .build import build_report, make_notebook, render_notebook
from .summary import build_summary, write_summary

__all__ = ["build_report", "make_notebook", "render_notebook", "build_summary", "write_summary"]
