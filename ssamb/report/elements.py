"""What a report section is made of: text, tables, images and figures (no notebook code).

A section function (:mod:`ssamb.report.sections`) returns a :class:`Section`; the notebook only
calls :func:`ssamb.report.render.show` on it. Tests inspect the same objects.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

__all__ = ["Text", "Table", "Image", "Plot", "Figures", "Section"]


@dataclass(frozen=True)
class Text:
    """Markdown text (its numbers are formatted from files, never typed in)."""

    markdown: str


@dataclass(frozen=True)
class Table:
    """A table: ``header`` and ``rows`` of values (numbers formatted with ``digits``
    significant digits by :func:`ssamb.report.tables.fmt`)."""

    header: Sequence[str]
    rows: Sequence[Sequence[Any]]
    caption: str | None = None
    digits: int = 4


@dataclass(frozen=True)
class Image:
    """A PNG written by a stage."""

    path: Path
    caption: str | None = None


@dataclass(frozen=True)
class Plot:
    """A matplotlib figure drawn by the section from stage data."""

    figure: Any
    caption: str | None = None


@dataclass(frozen=True)
class Figures:
    """Stage PNGs shown side by side, two per row, each with its caption (the report's first page)."""

    images: Sequence[Image]


@dataclass
class Section:
    """A titled list of elements.

    ``level`` is the markdown heading level of the title; a ``collapsed`` section is shown
    folded (an HTML ``<details>`` element the reader opens), as the appendices are.
    """

    title: str
    items: list = field(default_factory=list)
    level: int = 2
    collapsed: bool = False

    def add(self, *items) -> "Section":
        """Append elements (a plain string becomes :class:`Text`); returns the section."""
        self.items.extend(Text(i) if isinstance(i, str) else i for i in items if i is not None)
        return self

    def tables(self) -> list[Table]:
        """The section's tables, in order."""
        return [i for i in self.items if isinstance(i, Table)]

    def text(self) -> str:
        """All the markdown of the section, for tests and search."""
        return "\n".join([self.title] + [i.markdown for i in self.items if isinstance(i, Text)])

    def images(self) -> list[Image]:
        """Every image of the section, those in a :class:`Figures` grid included."""
        out = []
        for i in self.items:
            out += list(i.images) if isinstance(i, Figures) else [i] if isinstance(i, Image) else []
        return out
