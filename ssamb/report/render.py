"""Show a :class:`~ssamb.report.elements.Section` in the executing notebook (IPython display)."""
from __future__ import annotations

from .elements import Image, Plot, Section, Table, Text
from .tables import table

__all__ = ["show"]


def show(section: Section) -> None:
    """Display the section: heading, markdown, HTML tables, PNG images and figures."""
    import matplotlib.pyplot as plt
    from IPython.display import HTML, Markdown, display
    from IPython.display import Image as IPImage

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
        elif isinstance(item, Plot):
            display(item.figure)
            plt.close(item.figure)
            if item.caption:
                display(Markdown(f"*{item.caption}*"))
        else:
            raise TypeError(f"cannot show {type(item).__name__} in a report section")
