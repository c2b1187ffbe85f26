"""A run's failures, each reported once: the stage that failed and why, and the stages that did
not run because of it.

When a stage fails in a scenario or study run, every stage downstream of it reads a failure
marker and records a failure of its own whose reason quotes the upstream one
(``<file>: stage <name> failed: <reason>``, :func:`ssamb.model_io.check_failed`). A run's
``failed`` mapping (``summary.json``) therefore lists one root failure many times over; this
module follows each reason back to the stage where it began.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Mapping

__all__ = ["Failure", "root_cause", "group_failures", "failure_lines"]

_QUOTED = re.compile(r"stage (?P<stage>\S+) failed: ")
_WRAPPER = re.compile(r"^(?:Failed|DataError): ")
_STAGE_PREFIX = re.compile(r"^[a-z_]+(?:/[A-Za-z0-9_.=-]+)?: ")


@dataclass(frozen=True)
class Failure:
    """One failure at its root: the stage, its reason, and the stages it stopped."""

    stage: str
    reason: str
    stopped: tuple[str, ...] = ()

    def line(self) -> str:
        """One line: ``stage X failed: reason (not run because of it: a, b)``."""
        tail = f" (not run because of it: {', '.join(self.stopped)})" if self.stopped else ""
        return f"stage {self.stage} failed: {self.reason}{tail}"


def root_cause(stage: str, reason: str) -> tuple[str, str]:
    """The stage where a failure began and its own reason.

    Parameters
    ----------
    stage : str
        The stage that recorded the failure (a key of ``summary['failed']``).
    reason : str
        What it recorded; an upstream failure is quoted as ``stage <name> failed: <reason>``.

    Returns
    -------
    tuple of str
        ``(root stage, root reason)``; ``(stage, reason)`` when the reason quotes no other stage.

    Examples
    --------
    >>> from ssamb.report.failures import root_cause
    >>> root_cause("mu/all", "Failed: a.json: stage assemble failed: Failed: b.npz: stage select "
    ...            "failed: no stable loop")
    ('select', 'no stable loop')
    """
    reason = _STAGE_PREFIX.sub("", reason)
    found = list(_QUOTED.finditer(reason))
    if found:
        last = found[-1]
        stage, reason = last["stage"], reason[last.end():]
    return stage, _WRAPPER.sub("", reason).strip()


def group_failures(failed: Mapping[str, str] | None) -> list[Failure]:
    """Failures grouped by their root (:func:`root_cause`), in the order of ``failed``.

    A root that recorded no failure of its own (it wrote a failure marker only) still appears,
    with every stage that quoted it listed as stopped.
    """
    groups: dict[tuple[str, str], list[str]] = {}
    for stage, reason in (failed or {}).items():
        root = root_cause(stage, str(reason))
        groups.setdefault(root, [])
        if stage != root[0]:
            groups[root].append(stage)
    return [Failure(s, r, tuple(st)) for (s, r), st in groups.items()]


def failure_lines(failed: Mapping[str, str] | None) -> list[str]:
    """One line per root failure (:meth:`Failure.line`)."""
    return [f.line() for f in group_failures(failed)]
