"""Rows of the parameter tables: values and the reasons written beside them in ``config.yaml``."""
from __future__ import annotations

import re
from pathlib import Path

import yaml

__all__ = ["config_rows"]

_LINE = re.compile(r"^(?P<indent> *)(?P<key>[A-Za-z0-9_]+):(?P<rest>.*)$")


def config_rows(path: str | Path, skip_sections=("experiments", "closeloop")) -> tuple[list, list]:
    """``(table1_rows, assumption_rows)`` from a config file.

    Each leaf ``key: value  # reason`` gives a row; Table 1 rows are ``[key, value, meaning]``, the
    assumption rows ``[dotted key, value, reason]`` (the comment, or the section's comment).
    """
    text = Path(path).read_text(encoding="utf-8")
    cfg = yaml.safe_load(text)
    stack: list[tuple[int, str]] = []
    t1, other = [], []
    for line in text.splitlines():
        m = _LINE.match(line)
        if not m or line.lstrip().startswith("#"):
            continue
        ind = len(m["indent"])
        while stack and stack[-1][0] >= ind:
            stack.pop()
        key = m["key"]
        rest = m["rest"]
        value_part, _, comment = rest.partition(" #")
        dotted = ".".join([k for _, k in stack] + [key])
        if value_part.strip() == "":
            stack.append((ind, key))
            continue
        top = dotted.split(".")[0]
        if top in skip_sections:
            continue
        node = cfg
        for k in dotted.split("."):
            node = node[k]
        if top == "table1":
            t1.append([dotted.split(".", 1)[1], node, comment.strip()])
        else:
            other.append([dotted, node if not isinstance(node, (list, dict)) else str(node), comment.strip()])
    return t1, other
