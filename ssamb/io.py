"""Files: NPZ arrays with a JSON sidecar, the measured-data format, atomic writes.

Conventions (ARCHITECTURE.md)
-----------------------------
* Arrays go into ``NAME.npz``; metadata (config hash, seed, versions, ...) into ``NAME.json``
  beside it.
* Every writer is atomic: it writes to a temporary file in the target directory and renames,
  so a failure never leaves a half-written output.

Measured-data format
--------------------
``fs_hz`` (scalar), ``t`` (s), ``r_x``, ``r_y`` (m), ``x_meas``, ``y_meas`` (m), ``y_ss`` (m),
``i_ypos``, ``i_yneg``, ``i_xpos``, ``i_xneg`` (A), ``u_x``, ``u_y`` (A) and ``meta`` (a JSON
string describing the excitation). Optional extra columns are allowed.
"""
from __future__ import annotations

import json
import os
import platform
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Mapping

import numpy as np

__all__ = [
    "DataError",
    "MEASURED_COLUMNS",
    "atomic_path",
    "save_npz",
    "load_npz",
    "write_json",
    "read_json",
    "load_measured",
    "save_measured",
    "validate_measured",
    "versions",
]

#: Required columns of the measured-data format, in order (``fs_hz`` and ``meta`` aside).
MEASURED_COLUMNS = (
    "t", "r_x", "r_y", "x_meas", "y_meas", "y_ss",
    "i_ypos", "i_yneg", "i_xpos", "i_xneg", "u_x", "u_y",
)


class DataError(ValueError):
    """Input data break the measured-data format; the message names the file and the problem."""


@contextmanager
def atomic_path(path: str | Path, suffix: str | None = None):
    """Yield a temporary path next to ``path``; rename it onto ``path`` only on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix or path.suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _jsonable(o: Any):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_json(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as indented JSON, atomically (numpy scalars and arrays converted)."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(obj, fh, indent=2, default=_jsonable, allow_nan=True)
            fh.write("\n")


def read_json(path: str | Path) -> Any:
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def versions() -> dict:
    """Versions of the interpreter and the numerical packages, for provenance."""
    out = {"python": platform.python_version()}
    for mod in ("numpy", "scipy", "control", "numba", "snakemake", "matplotlib", "sippy_unipi"):
        try:
            m = __import__(mod)
            out[mod] = getattr(m, "__version__", "unknown")
        except Exception:  # pragma: no cover - optional at runtime
            try:
                from importlib.metadata import version

                out[mod] = version(mod.replace("_", "-"))
            except Exception:
                out[mod] = None
    return out


def save_npz(path: str | Path, arrays: Mapping[str, Any], meta: Mapping[str, Any] | None = None) -> None:
    """Save ``arrays`` to ``path`` (.npz) and, if given, ``meta`` to the ``.json`` beside it.

    A ``meta`` entry is also embedded in the NPZ as the JSON string ``meta`` so that the file is
    self-describing (the measured-data format requires it).
    """
    path = Path(path)
    payload = {k: np.asarray(v) for k, v in arrays.items()}
    if meta is not None:
        payload["meta"] = np.asarray(json.dumps(meta, default=_jsonable, sort_keys=True))
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **payload)
    if meta is not None:
        write_json(path.with_suffix(".json"), meta)


def load_npz(path: str | Path) -> tuple[dict, dict]:
    """Load arrays and metadata written by :func:`save_npz`; returns ``(arrays, meta)``."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: file not found")
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = {}
    if "meta" in arrays:
        meta = json.loads(str(arrays.pop("meta")))
    elif path.with_suffix(".json").exists():
        meta = read_json(path.with_suffix(".json"))
    return arrays, meta


def validate_measured(arrays: Mapping[str, Any], source: str = "data", min_samples: int = 16) -> None:
    """Check the measured-data format; raise :class:`DataError` naming every problem.

    Checks: required columns present (all missing ones named), ``fs_hz`` a positive scalar,
    equal lengths, finite values, ``t`` uniformly spaced at ``1/fs_hz``.
    """
    missing = [c for c in ("fs_hz",) + MEASURED_COLUMNS if c not in arrays]
    if missing:
        raise DataError(f"{source}: missing required column(s): {', '.join(missing)}")
    fs = np.asarray(arrays["fs_hz"], dtype=float)
    if fs.size != 1 or not np.isfinite(fs).all() or float(fs) <= 0:
        raise DataError(f"{source}: 'fs_hz' must be one positive number (got {arrays['fs_hz']!r})")
    fs = float(fs)
    n = len(np.asarray(arrays["t"]))
    for c in MEASURED_COLUMNS:
        a = np.asarray(arrays[c])
        if a.ndim != 1:
            raise DataError(f"{source}: column '{c}' must be one-dimensional (shape {a.shape})")
        if len(a) != n:
            raise DataError(f"{source}: column '{c}' has {len(a)} samples, 't' has {n}")
        if not np.issubdtype(a.dtype, np.number):
            raise DataError(f"{source}: column '{c}' is not numeric")
        bad = ~np.isfinite(a)
        if bad.any():
            raise DataError(f"{source}: column '{c}' has {int(bad.sum())} non-finite value(s) (NaN/inf), first at sample {int(np.argmax(bad))}")
    if n < min_samples:
        raise DataError(f"{source}: only {n} samples (need at least {min_samples})")
    dt = np.diff(np.asarray(arrays["t"], dtype=float))
    if not np.allclose(dt, 1.0 / fs, rtol=1e-3, atol=0):
        raise DataError(
            f"{source}: 'fs_hz' = {fs:g} Hz disagrees with the time column 't' "
            f"(median step {np.median(dt):.6g} s = {1.0 / np.median(dt):.6g} Hz) or 't' is not uniform"
        )


def load_measured(path: str | Path, min_samples: int = 16) -> tuple[dict, dict]:
    """Load measured data (``.npz``, or ``.csv`` with a ``.json`` sidecar) and validate it.

    The CSV form has a header row with the column names; its sidecar JSON holds ``fs_hz`` and
    ``meta`` (an object or a JSON string). Returns ``(arrays, meta)``.
    """
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: file not found")
    if path.suffix == ".npz":
        try:
            arrays, meta = load_npz(path)
        except (ValueError, OSError) as exc:
            raise DataError(f"{path}: not a readable NPZ file ({exc})") from None
    elif path.suffix == ".csv":
        side = path.with_suffix(".json")
        if not side.exists():
            raise DataError(f"{path}: CSV data need a JSON sidecar {side.name} with 'fs_hz' and 'meta'")
        sc = read_json(side)
        try:
            tab = np.genfromtxt(path, delimiter=",", names=True, dtype=float)
        except ValueError as exc:
            raise DataError(f"{path}: cannot parse CSV ({exc})") from None
        arrays = {name: np.asarray(tab[name]) for name in tab.dtype.names}
        if "fs_hz" not in sc:
            raise DataError(f"{side}: missing required key 'fs_hz'")
        arrays["fs_hz"] = np.asarray(float(sc["fs_hz"]))
        meta = sc.get("meta", {})
        if isinstance(meta, str):
            meta = json.loads(meta)
    else:
        raise DataError(f"{path}: unknown data format '{path.suffix}' (use .npz, or .csv with a .json sidecar)")
    validate_measured(arrays, str(path), min_samples=min_samples)
    return arrays, meta


def save_measured(path: str | Path, arrays: Mapping[str, Any], meta: Mapping[str, Any]) -> None:
    """Write measured data (validated first, so that nothing invalid is ever written)."""
    validate_measured(arrays, str(path))
    save_npz(path, arrays, meta)
