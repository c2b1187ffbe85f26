r"""Measured data of the levitated ball: the file formats, their checks, the levitated stretches.

Three formats are read, each into the same arrays ``t`` (s), ``y`` (m), ``i`` (A), ``u`` (V),
``yd`` (m) (float64, SI) and a ``meta`` mapping:

* the rig's own text logs (``dataset_*.txt`` of the acquisition program): latin-1 header lines
  starting with ``#`` (one of them ``# Columnas: t y y_obs dy_obs i u yd`` naming the columns),
  then tab-separated rows at 100 Hz; the columns ``y_obs``/``dy_obs`` are read and dropped;
* a plain CSV file whose header names at least ``t,y,i,u,yd`` (SI units; other columns ignored);
* the project's converted NPZ (``resources/maglev1d/*.npz``): the arrays ``t, y, i, u, yd`` and a
  JSON string ``meta`` (source file, its sha256, the reference profile).

Every problem raises :class:`ssamb.io.DataError`, one line naming the file and the column.

When the ball levitates
-----------------------
The ball is in one of three states: resting on the lower stop, pulled against the magnet's face
(the upper stop, :math:`y \approx 0`), or floating between them, carried by the magnet alone. A
ball held by something else (the operator's hand at the start of a log) is also away from both
stops, but without current in the coil: the reluctance force :math:`F = \tfrac12 i^2 |dL/dy|`
vanishes with :math:`i`, so a ball that floats with no current is not carried by the magnet. A
sample is therefore *levitated* when

.. math:: y_{top} + m \le y \le y_{bottom} - m \quad\text{and}\quad i \ge i_{min}

with the margin :math:`m` (far above the sensor's count and a bounce) and the current floor
:math:`i_{min}` from the device config (``levitation``). A *levitated stretch* is a run of
levitated samples lasting at least ``levitation.min_duration_s``; a log with none is rejected
("the ball never levitates").
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Mapping

import numpy as np

from ..io import DataError, load_npz, read_csv_columns

__all__ = ["COLUMNS", "load_data", "load_rig_log", "load_csv", "load_npz_record", "validate_arrays",
           "levitated_mask", "levitated_stretches", "sha256_of"]

#: the columns every format provides (SI: s, m, A, V, m)
COLUMNS = ("t", "y", "i", "u", "yd")
#: the rig's own log columns, in the order its header names them
RIG_LOG_COLUMNS = ("t", "y", "y_obs", "dy_obs", "i", "u", "yd")


def sha256_of(path: str | Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 16), b""):
            h.update(block)
    return h.hexdigest()


def load_data(path: str | Path) -> tuple[dict, dict]:
    """Read any of the three formats (by content: NPZ archive, ``#`` header, CSV header).

    Returns
    -------
    arrays : dict
        ``t, y, i, u, yd`` as float64 arrays (not yet validated: :func:`validate_arrays`).
    meta : dict
        ``format``, ``source`` and what the file says of itself (profile, header lines, ...).

    Raises
    ------
    ssamb.io.DataError
        A missing, empty or unreadable file, a missing column, a cell that is not a number.
    """
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: file not found")
    if path.is_dir():
        raise DataError(f"{path}: is a directory, not a data file")
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if not head.strip():
        raise DataError(f"{path}: empty file (no header, no data rows)")
    if head[:2] == b"PK":
        return load_npz_record(path)
    if head.lstrip()[:1] == b"#":
        return load_rig_log(path)
    return load_csv(path)


def load_rig_log(path: str | Path) -> tuple[dict, dict]:
    """The rig's text log: ``#`` header lines (latin-1), tab-separated numeric rows.

    The columns are those the header's ``Columnas:`` line names (else the acquisition program's
    order ``t y y_obs dy_obs i u yd``); ``y_obs`` and ``dy_obs`` (an observer's placeholders) are
    dropped.
    """
    path = Path(path)
    header, rows = [], []
    with open(path, encoding="latin-1") as fh:
        for line_no, line in enumerate(fh, 1):
            s = line.strip()
            if not s:
                continue
            if s.startswith("#"):
                header.append(s.lstrip("#").strip())
                continue
            rows.append((line_no, s))
    names = list(RIG_LOG_COLUMNS)
    for h in header:
        key, _, val = h.partition(":")
        if key.strip().lower() in ("columnas", "columns") and val.split():
            names = val.split()
    if not rows:
        raise DataError(f"{path}: no data rows below the '#' header")
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        raise DataError(f"{path}: column '{missing[0]}' missing (the header names {' '.join(names)})")
    tab = np.empty((len(rows), len(names)))
    for r, (line_no, s) in enumerate(rows):
        cells = s.split()
        if len(cells) != len(names):
            raise DataError(f"{path}: line {line_no} has {len(cells)} cells, the header names {len(names)} columns")
        for c, cell in enumerate(cells):
            try:
                tab[r, c] = float(cell)
            except ValueError:
                raise DataError(f"{path}: column '{names[c]}', line {line_no}: {cell!r} is not a number") from None
    arrays = {c: np.ascontiguousarray(tab[:, names.index(c)]) for c in COLUMNS}
    meta = {"format": "rig_log", "source": path.name, "header": header}
    for h in header:
        key, _, val = h.partition(":")
        if key.strip().lower() in ("perfil", "profile"):
            meta["profile"] = val.strip()
    return arrays, meta


def load_csv(path: str | Path) -> tuple[dict, dict]:
    """A CSV file whose header names at least ``t,y,i,u,yd`` (SI units); other columns ignored."""
    path = Path(path)
    cols = read_csv_columns(path)
    missing = [c for c in COLUMNS if c not in cols]
    if missing:
        raise DataError(f"{path}: column '{missing[0]}' missing (the header names {', '.join(cols)}; "
                        f"this device needs {', '.join(COLUMNS)})")
    return {c: np.ascontiguousarray(cols[c], dtype=float) for c in COLUMNS}, {"format": "csv", "source": path.name}


def load_npz_record(path: str | Path) -> tuple[dict, dict]:
    """The project's converted NPZ: arrays ``t, y, i, u, yd`` and a JSON string ``meta``."""
    path = Path(path)
    arrays, meta = load_npz(path)
    missing = [c for c in COLUMNS if c not in arrays]
    if missing:
        raise DataError(f"{path}: column '{missing[0]}' missing "
                        f"(the archive holds {', '.join(sorted(arrays)) or 'nothing'})")
    out = {}
    for c in COLUMNS:
        a = np.asarray(arrays[c])
        if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
            raise DataError(f"{path}: column '{c}' is not real numbers (dtype {a.dtype})")
        out[c] = np.ascontiguousarray(a, dtype=float)
    return out, {"format": "npz", "source": path.name, **dict(meta)}


def validate_arrays(arrays: Mapping, source: str, ts_s: float, min_samples: int = 16) -> None:
    """Check the arrays' shapes, values and time base; :class:`DataError` naming file and column.

    ``t`` must be uniform at the controller's period ``ts_s`` (the replay runs the rig's discrete
    controller once per sample): within 0.1 % per step, or, for a time written to 0.1 ms, within
    2 % per step with the mean step within 0.1 %.
    """
    for c in COLUMNS:
        if c not in arrays:
            raise DataError(f"{source}: column '{c}' missing")
    n = None
    for c in COLUMNS:
        a = np.asarray(arrays[c])
        if a.ndim != 1:
            raise DataError(f"{source}: column '{c}' must be one-dimensional (shape {a.shape})")
        if n is None:
            n = len(a)
        elif len(a) != n:
            raise DataError(f"{source}: column '{c}' has {len(a)} samples, column 't' has {n}")
        bad = ~np.isfinite(a)
        if bad.any():
            raise DataError(f"{source}: column '{c}' has {int(bad.sum())} non-finite value(s) (NaN/inf), "
                            f"first at sample {int(np.argmax(bad))}")
    if n < min_samples:
        raise DataError(f"{source}: column 't' has only {n} samples (need at least {min_samples})")
    t = np.asarray(arrays["t"], dtype=float)
    dt = np.diff(t)
    off = np.abs(dt - ts_s) > 1e-3 * ts_s
    # a time column written with few decimals (0.1 ms: the acquisition program's "%.4f" of an
    # accumulated t += Ts) steps by 0.0099/0.0101 s: consecutive samples all the same, when every
    # step is within 2 % of the period and their mean within 0.1 %
    if off.any() and np.all(np.abs(dt - ts_s) <= 2e-2 * ts_s) and abs(np.mean(dt) - ts_s) <= 1e-3 * ts_s:
        off[:] = False
    if off.any():
        k = int(np.argmax(off))
        raise DataError(f"{source}: column 't' is not a uniform time base at the controller's period "
                        f"{ts_s:g} s (sample {k + 1} is {dt[k]:.6g} s after the previous)")


def levitated_mask(y: np.ndarray, i: np.ndarray, top_m: float, bottom_m: float, margin_m: float,
                   min_current_a: float) -> np.ndarray:
    """Samples in which the magnet alone carries the ball (module docstring)."""
    y = np.asarray(y, float)
    i = np.asarray(i, float)
    return (y >= top_m + margin_m) & (y <= bottom_m - margin_m) & (i >= min_current_a)


def levitated_stretches(mask: np.ndarray, min_samples: int) -> list[tuple[int, int]]:
    """Runs ``[a, b)`` of True in ``mask`` at least ``min_samples`` long."""
    m = np.asarray(mask, bool).astype(np.int8)
    d = np.diff(np.concatenate(([0], m, [0])))
    starts, stops = np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]
    return [(int(a), int(b)) for a, b in zip(starts, stops) if b - a >= min_samples]
