"""Build, execute and render the HTML report (a Jupyter notebook made from ``results/``).

The notebook is generated cell by cell (:func:`make_notebook`): markdown that explains each
stage and code cells that read the stage outputs (JSON, NPZ, PNG) and show tables and
figures. It is executed with nbclient and exported by nbconvert to one self-contained HTML
file (figures embedded as base64). Every number of ours is read from ``summary.json`` or a
stage file while the notebook runs; the only typed numbers are quotations of the paper
(:mod:`ssamb.report.paper`).
"""
from __future__ import annotations

import json
import textwrap
from pathlib import Path
from typing import Iterable

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

__all__ = ["make_notebook", "render_notebook", "build_report"]


def _md(text: str):
    return new_markdown_cell(textwrap.dedent(text).strip())


def _code(text: str):
    return new_code_cell(textwrap.dedent(text).strip())


def make_notebook(results_dir: str | Path, sections: Iterable) -> nbformat.NotebookNode:
    """A notebook whose first cell sets up paths; ``sections`` are lists of cells."""
    results_dir = Path(results_dir).resolve()
    nb = new_notebook()
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    setup = f"""
    import json, warnings
    from pathlib import Path
    import numpy as np
    import matplotlib
    import matplotlib.pyplot as plt
    from IPython.display import HTML, Image, Markdown, display
    from ssamb.report import tables as T
    warnings.filterwarnings("ignore")
    plt.rcParams.update({{"figure.dpi": 110, "figure.figsize": (8.5, 3.6), "axes.grid": True}})
    R = Path({str(results_dir)!r})
    S = json.loads((R / "summary.json").read_text())
    """
    nb.cells.append(_code(setup))
    for cells in sections:
        nb.cells.extend(cells)
    return nb


def render_notebook(nb: nbformat.NotebookNode, out_html: str | Path, timeout_s: int = 600,
                    out_ipynb: str | Path | None = None) -> None:
    """Execute ``nb`` and write it as self-contained HTML (atomically); optionally keep the
    executed notebook too. The code cells are hidden in the HTML (the report is for readers
    of results; the notebook file holds the code)."""
    from nbclient import NotebookClient
    from nbconvert import HTMLExporter

    from ..io import atomic_path

    client = NotebookClient(nb, timeout=timeout_s, kernel_name="python3", allow_errors=False)
    client.execute()
    exporter = HTMLExporter(template_name="lab")
    exporter.exclude_input = True
    exporter.exclude_input_prompt = True
    exporter.exclude_output_prompt = True
    body, _ = exporter.from_notebook_node(nb)
    with atomic_path(out_html) as tmp:
        Path(tmp).write_text(body, encoding="utf-8")
    if out_ipynb is not None:
        with atomic_path(out_ipynb) as tmp:
            nbformat.write(nb, str(tmp))


def build_report(results_dir: str | Path, out_html: str | Path, out_ipynb: str | Path | None = None,
                 config_path: str | Path = "config.yaml", closeloop_dir: str | Path | None = None,
                 timeout_s: int = 600) -> None:
    """Build the full report from ``results_dir`` (needs ``summary.json`` and the stage files)."""
    from .sections import all_sections

    results_dir = Path(results_dir)
    summary = json.loads((results_dir / "summary.json").read_text())
    sections = all_sections(results_dir, summary, str(Path(config_path).resolve()),
                            None if closeloop_dir is None else str(Path(closeloop_dir).resolve()))
    nb = make_notebook(results_dir, sections)
    render_notebook(nb, out_html, timeout_s=timeout_s, out_ipynb=out_ipynb)
