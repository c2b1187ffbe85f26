"""Files: NPZ arrays with a JSON sidecar, the measured-data format, atomic writes.

Conventions (docs/formats.md)
-----------------------------
* Arrays go into ``NAME.npz``; metadata (config hash, seed, versions, ...) into ``NAME.json``
  beside it.
* Every writer is atomic: it writes to a temporary file in the target directory and renames,
  so a failure never leaves a half-written output. The file gets the permissions an ordinary
  ``open()`` would give it (``0o666`` less the umask), not the ``0o600`` of ``mkstemp``.
* A directory output (:func:`replace_dir`) is built whole in a temporary directory and swapped
  in, so it holds exactly the files of the last run.

Measured-data format
--------------------
``fs_hz`` (scalar), ``t`` (s), ``r_x``, ``r_y`` (m), ``x_meas``, ``y_meas`` (m), ``y_ss`` (m),
``i_ypos``, ``i_yneg``, ``i_xpos``, ``i_xneg`` (A), ``u_x``, ``u_y`` (A) and ``meta`` (a JSON
string describing the excitation). Optional extra columns are allowed. Every problem with a
data file raises :class:`DataError`, one line naming the file and the column or key.
"""
from __future__ import annotations

import csv
import errno
import json
import math
import os
import shutil
import tempfile
import warnings
import zipfile
import zlib
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from .errors import InputError, check_finite

__all__ = [
    "DataError",
    "MEASURED_COLUMNS",
    "atomic_path",
    "check_output_dir",
    "check_output_file",
    "replace_dir",
    "save_npz",
    "load_npz",
    "write_json",
    "read_json",
    "read_csv_columns",
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


class DataError(InputError):
    """Input data break the measured-data format; the message names the file and the problem."""


def _file_mode(directory: bool = False) -> int:
    """Permissions a new file (``0o666``) or directory (``0o777``) gets under the current umask."""
    mask = os.umask(0o022)      # the only portable way to read the umask is to set it
    os.umask(mask)
    return (0o777 if directory else 0o666) & ~mask


@contextmanager
def atomic_path(path: str | Path, suffix: str | None = None):
    """Yield a temporary path next to ``path``; rename it onto ``path`` only on success.

    The file ends with the permissions of an ordinary new file (the umask applies).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix or path.suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, _file_mode())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def check_replaceable(target: str | Path, owned: Callable[[Path], bool], label: str = "--out") -> None:
    """Raise :class:`InputError` unless ``target`` is absent, or a directory whose every entry
    ``owned`` accepts (a previous output of the same command), so that :func:`replace_dir`
    never deletes anything else."""
    target = Path(target)
    if not target.exists():
        return
    if not target.is_dir():
        raise InputError(f"{label} {target}: exists and is not a directory")
    foreign = sorted(p.name for p in target.iterdir() if not owned(p))
    if foreign:
        raise InputError(f"{label} {target}: holds files this command does not write ({', '.join(foreign[:3])}"
                         f"{', ...' if len(foreign) > 3 else ''}); give a new or empty directory")


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except OSError:              # a folder on the way that cannot be searched
        return True


def _check_writable(folder: Path, label: str, shown: Path) -> None:
    """Raise :class:`InputError` unless a file can be created in ``folder`` or, when it does not
    exist yet, in its nearest existing ancestor (which must be a folder). The probe creates and
    deletes a hidden temporary file, exactly what the atomic writers do: a read-only or full
    file system, a missing permission, an immutable folder all fail it."""
    anc = folder
    while not _exists(anc):
        anc = anc.parent
    if not anc.is_dir():
        raise InputError(f"{label} {shown}: '{anc}' is a file, not a folder")
    try:
        fd, tmp = tempfile.mkstemp(dir=anc, prefix=".ssamb-probe-")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise InputError(f"{label} {shown}: cannot write in the folder '{anc}' "
                         f"({exc.strerror or type(exc).__name__})") from None


def check_output_file(path: str | Path, force: bool = False, sidecar: bool = True, label: str = "--out") -> None:
    """Check where an output file (and its ``.json`` sidecar) goes, before any work.

    Raises :class:`InputError` (one line, naming ``label`` and the path) when the path is a
    folder, lies under a file, cannot be written (read-only folder), or when the file or its
    sidecar exists and ``force`` is false: a command never overwrites a file it did not create
    in that call unless told to. A sidecar that is a folder is an error even with ``force``.
    """
    path = Path(path)
    targets = [path] + ([path.with_suffix(".json")] if sidecar else [])
    for t in targets:
        if t.is_dir():
            what = "" if t == path else f"its sidecar {t.name} "
            raise InputError(f"{label} {path}: {what}is a folder")
    _check_writable(path.parent, label, path)
    if not force:
        existing = [t for t in targets if t.exists()]
        if existing:
            names = " and ".join(f"'{t}'" for t in existing)
            raise InputError(f"{label} {path}: {names} exist{'s' if len(existing) == 1 else ''}; "
                             "give --force to overwrite")


def check_output_dir(target: str | Path, owned: Callable[[Path], bool], force: bool = False,
                     label: str = "--out") -> None:
    """Check an output folder before any work: :func:`check_replaceable` (a file, or a folder
    with files the command does not write, is an error even with ``force``); a folder with a
    previous output needs ``force``; its parent must be writable (the new folder is built
    beside it and swapped in, :func:`replace_dir`)."""
    target = Path(target)
    check_replaceable(target, owned, label)
    if not force and target.is_dir() and any(target.iterdir()):
        raise InputError(f"{label} {target}: holds a previous output; give --force to replace it")
    _check_writable(target.parent, label, target)


def replace_dir(new: str | Path, target: str | Path, owned: Callable[[Path], bool], label: str = "--out") -> None:
    """Replace directory ``target`` by the complete directory ``new`` (on the same file system).

    The old ``target`` (checked with :func:`check_replaceable`) is renamed aside, ``new`` renamed
    onto ``target`` and the old one deleted: ``target`` holds exactly the files of ``new``, never a
    mixture. When another process puts its own ``target`` in place between the two renames, that
    one is moved aside too (the last writer wins, whole). ``new`` gets the umask's permissions.
    """
    new, target = Path(new), Path(target)
    os.chmod(new, _file_mode(directory=True))
    for _ in range(20):
        check_replaceable(target, owned, label)
        old = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".{target.name}.old."))
        try:
            if target.exists():
                os.rename(target, old / "prev")
            os.rename(new, target)
            return
        except FileNotFoundError:
            continue             # target vanished between exists() and rename(): try again
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                if (old / "prev").exists() and not target.exists():
                    os.rename(old / "prev", target)      # put the previous output back
                raise
        finally:
            shutil.rmtree(old, ignore_errors=True)
    raise OSError(f"{target}: could not be replaced (other writers kept recreating it)")


def jsonable(o: Any):
    """JSON ``default`` for the project's objects: NumPy scalars and arrays, paths (the one
    converter every JSON writer and hash uses)."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def plain(o: Any):
    """``o`` as strict JSON values: mappings with string keys, lists, finite numbers (NaN and
    infinities become None), NumPy scalars and arrays as Python values, complex numbers as
    ``{abs, angle_rad}``, paths as strings (the analysis reports' one converter)."""
    if isinstance(o, dict):
        return {str(k): plain(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [plain(v) for v in o]
    if isinstance(o, np.ndarray):
        return plain(o.tolist())
    if isinstance(o, np.generic):
        return plain(o.item())
    if isinstance(o, complex):
        return {"abs": abs(o), "angle_rad": math.atan2(o.imag, o.real)}
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, Path):
        return str(o)
    return o


def write_json(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as indented JSON, atomically (numpy scalars and arrays converted)."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(obj, fh, indent=2, default=jsonable, allow_nan=True)
            fh.write("\n")


def read_json(path: str | Path) -> Any:
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def versions() -> dict:
    """Versions of the interpreter and of every dependency, for provenance
    (:func:`ssamb.provenance.versions`)."""
    from .provenance import versions as _versions

    return _versions()


def save_npz(path: str | Path, arrays: Mapping[str, Any], meta: Mapping[str, Any] | None = None,
             compress: bool = False) -> None:
    """Save ``arrays`` to ``path`` (.npz) and, if given, ``meta`` to the ``.json`` beside it.

    A ``meta`` entry is also embedded in the NPZ as the JSON string ``meta`` so that the file is
    self-describing (the measured-data format requires it). ``compress`` deflates the members
    (like ``numpy.savez_compressed``). The archive is byte-reproducible (:func:`_write_npz`).
    """
    path = Path(path)
    payload = {k: np.asarray(v) for k, v in arrays.items()}
    if meta is not None:
        payload["meta"] = np.asarray(json.dumps(meta, default=jsonable, sort_keys=True))
    if meta is None:
        with atomic_path(path, suffix=".npz") as tmp:
            _write_npz(tmp, payload, compress)
        return
    # both files written to temporary names first: a sidecar that cannot be written leaves
    # neither file (the sidecar is renamed into place first, the archive last)
    with atomic_path(path, suffix=".npz") as tmp:
        _write_npz(tmp, payload, compress)
        write_json(path.with_suffix(".json"), meta)


def _write_npz(path: Path, payload: Mapping[str, np.ndarray], compress: bool) -> None:
    """An NPZ archive (a zip of ``NAME.npy`` members, what ``numpy.load`` reads) whose bytes
    depend on the arrays only: ``numpy.savez`` stamps every member with the current time, so no
    two runs would give the same checksum. Members carry a fixed 1980-01-01 time stamp."""
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, "w", compression=method, allowZip64=True) as zf:
        for name, arr in payload.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = method
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=False)


#: what NumPy raises for a file that is not a readable NPZ (empty, cut short, a damaged member)
_NPZ_ERRORS = (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error)


def load_npz(path: str | Path) -> tuple[dict, dict]:
    """Load arrays and metadata written by :func:`save_npz`; returns ``(arrays, meta)``.

    ``meta`` comes from the member ``meta`` (a JSON string) or else from the ``.json`` beside
    the file. Raises :class:`DataError` (naming the file) for a missing, empty, truncated or
    damaged file and for a ``meta`` that is not a JSON object.
    """
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: file not found")
    if path.is_file() and path.stat().st_size == 0:
        raise DataError(f"{path}: empty file (not a readable NPZ file)")
    try:
        z = np.load(path, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise DataError(f"{path}: not an NPZ archive (a single .npy array)")
        with z:
            arrays = {k: z[k] for k in z.files}
    except DataError:
        raise
    except _NPZ_ERRORS as exc:
        raise DataError(f"{path}: not a readable NPZ file ({type(exc).__name__}: "
                        f"{' '.join(str(exc).split()) or 'empty'})") from None
    if "meta" in arrays:
        meta = _parse_meta(str(arrays.pop("meta")), f"{path}: member 'meta'")
    elif path.with_suffix(".json").exists():
        meta = _read_json_object(path.with_suffix(".json"))
    else:
        meta = {}
    return arrays, meta


def _read_json_object(path: Path) -> dict:
    """The JSON object in ``path``; :class:`DataError` naming the file otherwise."""
    try:
        obj = read_json(path)
    except (ValueError, OSError) as exc:   # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise DataError(f"{path}: not valid JSON ({' '.join(str(exc).split())})") from None
    if not isinstance(obj, dict):
        raise DataError(f"{path}: top level must be a JSON object")
    return obj


def _parse_meta(text: Any, where: str) -> dict:
    if isinstance(text, Mapping):
        return dict(text)
    try:
        meta = json.loads(str(text))
    except ValueError as exc:
        raise DataError(f"{where}: not valid JSON ({' '.join(str(exc).split())})") from None
    if not isinstance(meta, dict):
        raise DataError(f"{where}: must be a JSON object describing the excitation")
    return meta


#: what the loaders check of ``meta`` (the keys the analysis reads; any others are free)
_META_SCHEMA = {
    "type": "object",
    "properties": {
        "excitation": {
            "type": "object",
            "properties": {
                "kind": {"type": "string"},
                "point": {"enum": ["position", "current"]},
                "axis": {"enum": ["x", "y", "both"]},
                "seed": {"type": ["integer", "null"], "minimum": 0},
                "samples_per_period": {"type": "integer", "minimum": 1},
                "lines_hz": {"type": "array", "items": {"type": "number"}},
            },
        },
        "start": {"enum": ["levitated", "rest"]},
        "settle_s": {"type": "number", "minimum": 0},
        "fs_hz": {"type": "number", "exclusiveMinimum": 0},
    },
}


def validate_meta(meta: Any, where: str) -> None:
    """Check a data file's ``meta``: a mapping, finite numbers only, and the types of the keys
    the analysis reads (:data:`_META_SCHEMA`); :class:`DataError` naming ``where`` and the key."""
    import jsonschema

    if not isinstance(meta, Mapping):
        raise DataError(f"{where}: 'meta' must be a JSON object describing the excitation")
    check_finite(meta, where, DataError, what="meta key")
    for err in jsonschema.Draft202012Validator(_META_SCHEMA).iter_errors(meta):
        key = ".".join(str(k) for k in err.absolute_path)
        raise DataError(f"{where}: meta key '{key}': {err.message}")


def validate_measured(arrays: Mapping[str, Any], source: str = "data", min_samples: int = 16) -> None:
    """Check the measured-data format; raise :class:`DataError` naming the file and the column.

    Checks: required columns present (all missing ones named), ``fs_hz`` a positive scalar,
    real numeric one-dimensional columns of equal length, finite values, ``t`` uniformly spaced
    at ``1/fs_hz``.
    """
    missing = [c for c in ("fs_hz",) + MEASURED_COLUMNS if c not in arrays]
    if missing:
        raise DataError(f"{source}: missing required column(s): {', '.join(missing)}")
    fs = np.asarray(arrays["fs_hz"])
    if fs.size != 1 or not _is_real(fs) or not np.isfinite(fs).all() or float(fs.ravel()[0]) <= 0:
        raise DataError(f"{source}: 'fs_hz' must be one positive number (got {arrays['fs_hz']!r})")
    fs = float(fs.ravel()[0])
    n = len(np.atleast_1d(np.asarray(arrays["t"])))
    for c in MEASURED_COLUMNS:
        a = np.asarray(arrays[c])
        if a.ndim != 1:
            raise DataError(f"{source}: column '{c}' must be one-dimensional (shape {a.shape})")
        if len(a) != n:
            raise DataError(f"{source}: column '{c}' has {len(a)} samples, 't' has {n}")
        if not _is_real(a):
            raise DataError(f"{source}: column '{c}' is not real numbers (dtype {a.dtype})")
        bad = ~np.isfinite(a)
        if bad.any():
            raise DataError(f"{source}: column '{c}' has {int(bad.sum())} non-finite value(s) (NaN/inf), first at "
                            f"sample {int(np.argmax(bad))}")
    if n < min_samples:
        raise DataError(f"{source}: only {n} samples (need at least {min_samples})")
    dt = np.diff(np.asarray(arrays["t"], dtype=float))
    if not np.allclose(dt, 1.0 / fs, rtol=1e-3, atol=0):
        raise DataError(
            f"{source}: 'fs_hz' = {fs:g} Hz disagrees with the time column 't' "
            f"(median step {np.median(dt):.6g} s = {1.0 / np.median(dt):.6g} Hz) or 't' is not uniform"
        )


def _is_real(a: np.ndarray) -> bool:
    return np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)


def read_csv_columns(path: str | Path) -> dict[str, np.ndarray]:
    """The columns of a CSV file with a header row of names, as float arrays.

    Raises :class:`DataError` naming the file for an empty file, a header without names or
    with a repeated name, a row with the wrong number of cells, and a cell that is not a number
    (with its column and line). ``nan``/``inf`` cells parse; the format checks reject them.
    """
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            header = next(csv.reader(fh), None)
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a UTF-8 text (CSV) file") from None
    except OSError as exc:              # a directory, no permission, an I/O error
        raise DataError(f"{path}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    names = [h.strip() for h in header or []]
    if not any(names):
        raise DataError(f"{path}: empty (a CSV data file starts with a header row of column names)")
    if "" in names:
        raise DataError(f"{path}: header cell {names.index('') + 1} has no column name")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DataError(f"{path}: column '{dup[0]}' appears more than once in the header")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)     # "input contained no data"
            tab = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=float, encoding="utf-8")
    except ValueError as exc:
        _diagnose_csv(path, names)
        raise DataError(f"{path}: cannot parse CSV ({' '.join(str(exc).split())})") from None
    if tab.shape[0] == 0:
        raise DataError(f"{path}: no data rows below the header")
    if tab.shape[1] != len(names):
        raise DataError(f"{path}: rows have {tab.shape[1]} cells, the header names {len(names)} columns")
    return {name: np.ascontiguousarray(tab[:, i]) for i, name in enumerate(names)}


def _diagnose_csv(path: Path, names: list[str]) -> None:
    """Find the first bad row or cell of a CSV that NumPy could not parse; raise DataError."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = csv.reader(fh)
        next(rows)
        for row in rows:
            if not row or (len(row) == 1 and not row[0].strip()):
                continue
            line = rows.line_num
            if len(row) != len(names):
                raise DataError(f"{path}: line {line} has {len(row)} cells, the header names {len(names)} columns")
            for name, cell in zip(names, row):
                try:
                    float(cell)
                except ValueError:
                    raise DataError(f"{path}: column '{name}', line {line}: {cell.strip()!r} is not a number") from None


def _load_csv(path: Path) -> tuple[dict, dict]:
    """A CSV data file and its JSON sidecar (``fs_hz`` and ``meta``)."""
    side = path.with_suffix(".json")
    if not side.exists():
        raise DataError(f"{path}: CSV data need a JSON sidecar {side.name} with 'fs_hz' and 'meta'")
    sc = _read_json_object(side)
    check_finite(sc, str(side), DataError)
    if "fs_hz" not in sc:
        raise DataError(f"{side}: key 'fs_hz': missing (required)")
    fs = sc["fs_hz"]
    if isinstance(fs, bool) or not isinstance(fs, (int, float)) or fs <= 0:
        raise DataError(f"{side}: key 'fs_hz': must be a positive number (got {fs!r})")
    arrays = read_csv_columns(path)
    if "fs_hz" in arrays:
        raise DataError(f"{path}: column 'fs_hz' is not allowed (the sampling rate goes into {side.name})")
    arrays["fs_hz"] = np.asarray(float(fs))
    meta = _parse_meta(sc.get("meta", {}), f"{side}: key 'meta'")
    return arrays, meta


def load_measured(path: str | Path, min_samples: int = 16) -> tuple[dict, dict]:
    """Load measured data (``.npz``, or ``.csv`` with a ``.json`` sidecar) and validate it.

    The CSV form has a header row with the column names; its sidecar JSON holds ``fs_hz`` and
    ``meta`` (an object or a JSON string). Returns ``(arrays, meta)``.

    Raises
    ------
    DataError
        Anything wrong with the file, its columns or its ``meta`` (one line naming the file and
        the column or key).
    """
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: file not found")
    if path.suffix == ".npz":
        arrays, meta = load_npz(path)
        where = str(path)
    elif path.suffix == ".csv":
        arrays, meta = _load_csv(path)
        where = str(path.with_suffix(".json"))
    else:
        raise DataError(f"{path}: unknown data format '{path.suffix}' (use .npz, or .csv with a .json sidecar)")
    validate_meta(meta, where)
    validate_measured(arrays, str(path), min_samples=min_samples)
    return arrays, meta


def save_measured(path: str | Path, arrays: Mapping[str, Any], meta: Mapping[str, Any],
                  compress: bool = False) -> None:
    """Write measured data (validated first, so that nothing invalid is ever written)."""
    validate_measured(arrays, str(path))
    validate_meta(meta, str(path))
    save_npz(path, arrays, meta, compress=compress)
