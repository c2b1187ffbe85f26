"""Show a :class:`~ssamb.report.elements.Section` in the executing notebook (IPython display).

An open section is shown element by element (markdown, HTML tables, PNGs, figures). A
``collapsed`` section is shown as one HTML ``<details>`` element, folded until the reader opens
it; its markdown is converted with mistune (nbconvert's own markdown renderer).
"""
from __future__ import annotations

import base64
import html
import io
from pathlib import Path

from .elements import Figures, Image, Plot, Section, Table, Text
from .tables import table

__all__ = ["show", "section_html"]


def _png_tag(data: bytes, width: str = "100%") -> str:
    return f'<img style="width:{width}" src="data:image/png;base64,{base64.b64encode(data).decode()}"/>'


def _figures_html(fig: Figures) -> str:
    cells = []
    for im in fig.images:
        cap = f'<div style="font-size:0.9em"><i>{html.escape(im.caption)}</i></div>' if im.caption else ""
        cells.append(f'<div style="width:49%;display:inline-block;vertical-align:top;margin:0 0.5% 8px 0">'
                     f"{_png_tag(Path(im.path).read_bytes())}{cap}</div>")
    return f'<div>{"".join(cells)}</div>'


def _markdown_html(text: str) -> str:
    import mistune

    return mistune.html(text)


def _item_html(item) -> str:
    if isinstance(item, Text):
        return _markdown_html(item.markdown)
    if isinstance(item, Table):
        cap = f"<p><b>{html.escape(item.caption)}</b></p>" if item.caption else ""
        return cap + table(item.rows, item.header, item.digits)
    if isinstance(item, Image):
        cap = f"<p><i>{html.escape(item.caption)}</i></p>" if item.caption else ""
        return _png_tag(Path(item.path).read_bytes()) + cap
    if isinstance(item, Figures):
        return _figures_html(item)
    if isinstance(item, Plot):
        import matplotlib.pyplot as plt

        buf = io.BytesIO()
        item.figure.savefig(buf, format="png")
        plt.close(item.figure)
        cap = f"<p><i>{html.escape(item.caption)}</i></p>" if item.caption else ""
        return _png_tag(buf.getvalue()) + cap
    raise TypeError(f"cannot show {type(item).__name__} in a report section")


def section_html(section: Section) -> str:
    """A collapsed section as one HTML ``<details>`` element (title in the ``<summary>``)."""
    body = "".join(_item_html(i) for i in section.items)
    return (f'<details><summary style="font-size:1.3em;font-weight:bold;cursor:pointer">'
            f"{html.escape(section.title)}</summary>{body}</details>")


def show(section: Section) -> None:
    """Display the section: heading, markdown, HTML tables, PNG images and figures."""
    import matplotlib.pyplot as plt
    from IPython.display import HTML, Markdown, display
    from IPython.display import Image as IPImage

    if section.collapsed:
        display(HTML(section_html(section)))
        return
    display(Markdown("#" * section.level + " " + section.title))
    for item in section.items:
        if isinstance(item, Text):
            display(Markdown(item.markdown))
        elif isinstance(item, Table):
            if item.caption:
                display(Markdown(f"**{item.caption}**"))
            display(HTML(table(item.rows, item.header, item.digits)))
        elif isinstance(item, Image):
            display(IPImage(filename=str(item.path)))
            if item.caption:
                display(Markdown(f"*{item.caption}*"))
        elif isinstance(item, Figures):
            display(HTML(_figures_html(item)))
        elif isinstance(item, Plot):
            display(item.figure)
            plt.close(item.figure)
            if item.caption:
                display(Markdown(f"*{item.caption}*"))
        else:
            raise TypeError(f"cannot show {type(item).__name__} in a report section")
