"""Build, execute and render the HTML report.

The notebook (:func:`make_notebook`) is one setup cell and one cell per section, each calling a
section function of :mod:`ssamb.report.sections` and showing what it returns
(:func:`ssamb.report.render.show`): the notebook holds no logic and no number. It is executed with
nbclient and exported by nbconvert to one self-contained HTML file (figures embedded). The only
typed numbers in the report are quotations of the paper (:mod:`ssamb.paper`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import nbformat
from nbformat.v4 import new_code_cell, new_notebook

from .sections import ORDER

__all__ = ["make_notebook", "render_notebook", "build_report"]


def make_notebook(results_dir: str | Path, config_path: str | Path, closeloop_dir: str | Path | None = None,
                  study_json: str | Path | None = None, sections: Sequence[str] = ORDER,
                  ensemble_json: str | Path | None = None) -> nbformat.NotebookNode:
    """The report notebook: a setup cell (the :class:`~ssamb.report.context.Context`) and one cell
    per section name."""
    nb = new_notebook()
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    cl = None if closeloop_dir is None else str(Path(closeloop_dir).resolve())
    st = None if study_json is None else str(Path(study_json).resolve())
    en = None if ensemble_json is None else str(Path(ensemble_json).resolve())
    nb.cells.append(new_code_cell(
        "import warnings\nimport matplotlib\nmatplotlib.use('Agg')\nimport matplotlib.pyplot as plt\n"
        "from ssamb.report import sections\nfrom ssamb.report.context import load_context\n"
        "from ssamb.report.render import show\nwarnings.filterwarnings('ignore')\n"
        "plt.rcParams.update({'figure.dpi': 110, 'axes.grid': True})\n"
        f"ctx = load_context({str(Path(results_dir).resolve())!r}, {str(Path(config_path).resolve())!r}, {cl!r}, "
        f"{st!r}, {en!r})"))
    for name in sections:
        nb.cells.append(new_code_cell(f"sec = sections.{name}(ctx)\nif sec is not None:\n    show(sec)"))
    return nb


def render_notebook(nb: nbformat.NotebookNode, out_html: str | Path, timeout_s: int = 600,
                    out_ipynb: str | Path | None = None) -> None:
    """Execute ``nb`` and write it as self-contained HTML (atomically); optionally keep the
    executed notebook too. Code cells are hidden in the HTML."""
    from nbclient import NotebookClient
    from nbconvert import HTMLExporter

    from ..io import atomic_path

    NotebookClient(nb, timeout=timeout_s, kernel_name="python3", allow_errors=False).execute()
    exporter = HTMLExporter(template_name="lab")
    exporter.exclude_input = exporter.exclude_input_prompt = exporter.exclude_output_prompt = True
    body, _ = exporter.from_notebook_node(nb)
    with atomic_path(out_html) as tmp:
        Path(tmp).write_text(body, encoding="utf-8")
    if out_ipynb is not None:
        with atomic_path(out_ipynb) as tmp:
            nbformat.write(nb, str(tmp))


def build_report(results_dir: str | Path, out_html: str | Path, out_ipynb: str | Path | None = None,
                 config_path: str | Path = "config.yaml", closeloop_dir: str | Path | None = None,
                 study_json: str | Path | None = None, timeout_s: int = 600,
                 ensemble_json: str | Path | None = None) -> None:
    """Build the full report from a results folder.

    Parameters
    ----------
    results_dir : path
        The run's results (``summary.json`` and the stage files).
    out_html : path
        The self-contained HTML report, written atomically.
    out_ipynb : path, optional
        Also keep the executed notebook.
    config_path : path
        The run's configuration (its comments give the reasons in the configuration appendix).
    closeloop_dir : path, optional
        The default close-the-loop data set's analysis folder.
    study_json : path, optional
        The assumption study (``results/study/study.json``), when it has run.
    timeout_s : int
        Longest a section's cell may run.
    ensemble_json : path, optional
        The noise ensembles (``results/ensemble/ensemble.json``), when they have run.

    Examples
    --------
    >>> from ssamb.report import build_report
    >>> build_report("results", "results/report.html", config_path="config.yaml",
    ...              closeloop_dir="results/closeloop/rig_demo")
    """
    render_notebook(make_notebook(results_dir, config_path, closeloop_dir, study_json, ensemble_json=ensemble_json),
                    out_html, timeout_s=timeout_s, out_ipynb=out_ipynb)
