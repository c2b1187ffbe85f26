"""Input errors and the checks every input reader shares.

Every error that bad *input* causes (a config value, a scenario key, a data file) is an
:class:`InputError`; the command line turns exactly these into one line and exit status 2
(``ssamb.cli``). Anything else (a ``KeyError``, a ``TypeError``, a LAPACK failure) is a
programming error and keeps its traceback.

The subclasses live beside the readers that raise them (:class:`ssamb.config.ConfigError`,
:class:`ssamb.io.DataError`, :class:`ssamb.rig.ScenarioError`,
:class:`ssamb.sim.effects.EffectError`); this module imports nothing of the package, so every
module can import it.
"""
from __future__ import annotations

import math
import numbers
from typing import Any, Iterator

__all__ = ["InputError", "nonfinite_keys", "check_finite"]


class InputError(ValueError):
    """Bad input; the message is one line naming the file and the key or column."""


def nonfinite_keys(obj: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """Yield ``(dotted_key, value)`` for every NaN or infinite number anywhere in ``obj``.

    Walks mappings (``a.b``), lists and tuples (``a[2]``); booleans, integers, strings and
    ``None`` are finite by definition. YAML reads ``.nan``/``.inf`` and Python's JSON reader
    ``NaN``/``Infinity`` as floats, which pass JSON Schema's ``minimum``/``maximum`` (every
    comparison with NaN is false), so this walk is what keeps them out.
    """
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from nonfinite_keys(v, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            yield from nonfinite_keys(v, f"{prefix}[{i}]")
    elif isinstance(obj, numbers.Real) and not isinstance(obj, bool) and not math.isfinite(float(obj)):
        yield prefix or "<value>", obj


def check_finite(obj: Any, where: str, error: type[InputError] = InputError, what: str = "key") -> None:
    """Raise ``error("{where}: {what} 'K': must be a finite number (got nan)")`` for the first
    non-finite number in ``obj`` (see :func:`nonfinite_keys`)."""
    for key, value in nonfinite_keys(obj):
        raise error(f"{where}: {what} '{key}': must be a finite number (got {value!r})")
