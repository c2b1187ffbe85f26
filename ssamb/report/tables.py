"""Small HTML table helpers used inside the report notebook."""
from __future__ import annotations

import html
import math
from typing import Any, Iterable, Sequence

__all__ = ["table", "fmt"]


def fmt(v: Any, digits: int = 4) -> str:
    """Format a number with ``digits`` significant digits; None -> 'none'; strings unchanged."""
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int,)) and not isinstance(v, bool):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "n/a"
        if math.isinf(v):
            return "inf"
        if 1e-3 <= abs(v) < 10 ** digits * 100:  # plain notation, ``digits`` significant digits
            dec = max(0, digits - 1 - math.floor(math.log10(abs(v))))
            text = f"{round(v, dec):.{dec}f}"
            return text.rstrip("0").rstrip(".") if "." in text else text
        return f"{v:.{digits}g}"
    return html.escape(str(v))


def table(rows: Iterable[Sequence[Any]], header: Sequence[str], digits: int = 4) -> str:
    """An HTML table (cells formatted by :func:`fmt`; a cell that is already HTML is kept)."""
    out = ['<table style="border-collapse:collapse;font-size:0.92em">', "<thead><tr>"]
    out += [f'<th style="border-bottom:1px solid #888;padding:3px 8px;text-align:left">{html.escape(h)}</th>'
            for h in header]
    out.append("</tr></thead><tbody>")
    for r in rows:
        out.append("<tr>")
        for c in r:
            cell = c[6:] if isinstance(c, str) and c.startswith("<html>") else fmt(c, digits)
            out.append(f'<td style="border-bottom:1px solid #ddd;padding:3px 8px">{cell}</td>')
        out.append("</tr>")
    out.append("</tbody></table>")
    return "".join(out)
