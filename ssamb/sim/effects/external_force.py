r"""``external_force``: an arbitrary force on the rotor, for tests.

Physics: :math:`(F_x(t), F_y(t))` from a CSV file (columns ``t, fx_n, fy_n``) or from arrays,
linearly interpolated at the simulator's samples. Close the loop does not look for it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ._common import EffectError

NAME = "external_force"
REQUIRED = ()
OPTIONAL = ("file", "t", "fx_n", "fy_n")
SIGNATURE = "an arbitrary force (a test tool; not searched)"
SEARCHABLE = False
NEEDS_HINT = True
ORDER = 99


#: the columns of a force table (a CSV file's header, or the inline arrays)
FORCE_COLUMNS = ("t", "fx_n", "fy_n")


def validate(p: dict, where: str) -> dict:
    if "file" not in p and not all(k in p for k in FORCE_COLUMNS):
        raise EffectError(f"{where}: give 'file' (CSV with t, fx_n, fy_n) or arrays t, fx_n, fy_n")
    if "file" in p and any(k in p for k in FORCE_COLUMNS):
        raise EffectError(f"{where}: give either 'file' or the arrays t, fx_n, fy_n, not both")
    if "file" not in p:
        check_force_table({k: np.asarray(p[k], float) for k in FORCE_COLUMNS}, where, EffectError, what="parameter")
    return p


def check_force_table(cols, where: str, error=EffectError, what: str = "column",
                      header_lines: int | None = None) -> None:
    """Check a force table like a measured-data file: exactly the columns :data:`FORCE_COLUMNS`,
    of equal length, finite numbers, ``t`` strictly increasing (the force is interpolated
    linearly in ``t`` and held at its end values outside the table; a ``t`` that turns back
    would interpolate between the wrong rows). ``error(f"{where}: {what} 'K': ...")`` names the
    column and, for a bad value, its position: the file's line when ``header_lines`` is given
    (the data start below that many lines), else the entry (1 = the first)."""

    def at(k: int) -> str:
        return f"line {k + 1 + header_lines}" if header_lines is not None else f"entry {k + 1}"

    missing = [c for c in FORCE_COLUMNS if c not in cols]
    if missing:
        raise error(f"{where}: missing {what}(s) {', '.join(missing)} (a force table has t, fx_n, fy_n)")
    extra = [c for c in cols if c not in FORCE_COLUMNS]
    if extra:
        raise error(f"{where}: {what} '{extra[0]}' is unknown (a force table has t, fx_n, fy_n)")
    n = len(cols["t"])
    for c in FORCE_COLUMNS:
        a = np.asarray(cols[c])
        if a.ndim != 1 or len(a) != n or n == 0:
            raise error(f"{where}: {what} '{c}' has {a.size} values, 't' has {n} (need the same number, at least one)")
        bad = ~np.isfinite(a)
        if bad.any():
            first = at(int(np.argmax(bad)))
            raise error(f"{where}: {what} '{c}', {first}: {float(a[bad][0])!r} is not a finite number")
    step = np.diff(np.asarray(cols["t"], float))
    if (step <= 0).any():
        k = int(np.argmax(step <= 0))
        raise error(f"{where}: {what} 't' must increase strictly: {at(k + 1)} ({float(cols['t'][k + 1])!r}) "
                    f"does not follow {at(k)} ({float(cols['t'][k])!r})")


def read_force_file(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""The force table of an ``external_force`` file: ``(t, fx_n, fy_n)`` in s and N.

    The file is a CSV with a header row naming exactly ``t, fx_n, fy_n`` (any order), read and
    checked like a measured-data file (:func:`ssamb.io.read_csv_columns`: a text or empty cell,
    a short row, a binary file are errors naming the line) and then by
    :func:`check_force_table` (no NaN or infinity, ``t`` strictly increasing).

    Raises
    ------
    ssamb.io.DataError
        One line naming the file and the column (and the line of a bad value).
    """
    from ...io import DataError, read_csv_columns

    path = Path(path)
    if not path.is_file():
        what = "is a folder" if path.is_dir() else "not found"
        raise DataError(f"{path}: {what} (an external force is a CSV file with the columns t, fx_n, fy_n)")
    cols = read_csv_columns(path)
    check_force_table(cols, str(path), DataError, header_lines=1)
    return tuple(np.asarray(cols[c], float) for c in FORCE_COLUMNS)


def apply(e: dict, ov: dict, f_x, f_y, t, base_dir) -> None:
    if "file" in e:
        path = Path(e["file"])
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        te, fxe, fye = read_force_file(path)
    else:
        te, fxe, fye = (np.asarray(e[k], float) for k in ("t", "fx_n", "fy_n"))
    f_x += np.interp(t, te, fxe)
    f_y += np.interp(t, te, fye)


def evidence(ft, alpha: float, st) -> dict:
    return {"score": 0.0, "log10_p": 0.0, "significant": False, "hints": {}, "details": {}}


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return 0.0


def model(hints: dict, record, st) -> str:
    return "an arbitrary force is a test tool, not a library effect"


def report(m, theta, se, significant) -> list[dict]:
    return []
