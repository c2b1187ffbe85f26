r"""Model files: identified subsystem models, state-space systems and uncertainty weights.

Each is an NPZ of arrays with a JSON sidecar (:func:`ssamb.io.save_npz`), read back into the
objects the stages work with.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Mapping

import numpy as np

if TYPE_CHECKING:  # python-control and the identification are imported where a model is built (slow to import)
    import control

    from .identification import IdentifiedModel
from .io import DataError, atomic_path, load_npz, read_json, save_npz, write_json

__all__ = ["Failed", "save_failed", "write_failed", "check_failed", "failure_reason", "load_record",
           "save_model", "load_model", "save_candidates", "load_candidates", "save_statespace", "load_statespace",
           "save_weight", "load_weight"]

_ARRAYS = ("A", "B", "C", "D", "u_op", "y_op")


def _model_arrays(model: IdentifiedModel) -> dict:
    arrays = {k: np.asarray(getattr(model, k), dtype=float) for k in _ARRAYS}
    if model.K is not None:
        arrays["K"] = np.asarray(model.K, dtype=float)
    return arrays


def _model_meta(model: IdentifiedModel) -> dict:
    return {
        "kind": "ssamb.IdentifiedModel",
        "dt": model.dt,
        "fs_hz": model.fs_hz,
        "order": model.order,
        "method": model.method,
        "input_names": list(model.input_names),
        "output_names": list(model.output_names),
        "affine": model.affine,
        "data_hash": model.data_hash,
        "ss_f": model.ss_f,
        "ss_p": model.ss_p,
        "spectral_radius": model.spectral_radius,
        "info": model.info,
    }


def save_model(path: str | Path, model: IdentifiedModel) -> None:
    """Write ``model`` to ``path`` (.npz arrays) with a JSON sidecar (names, method, hash ...)."""
    save_npz(path, _model_arrays(model), _model_meta(model))


class Failed(DataError):
    """A stage output records a failure (:func:`write_failed`), not a result."""


def save_failed(path: str | Path, reason: str, meta: Mapping | None = None) -> None:
    """Write a *failed* NPZ in place of a result: the rule's output exists, and whoever reads it
    learns that and why the stage failed (the loaders here raise :class:`Failed`)."""
    save_npz(path, {}, {"kind": "ssamb.Failed", "reason": str(reason), **dict(meta or {})})


def write_failed(path: str | Path, reason: str, stage: str) -> None:
    """A failure marker in the format of ``path``: NPZ (:func:`save_failed`), JSON
    (``{"failed": true, "stage", "error"}``), PNG (a figure stating the failure), else text."""
    path = Path(path)
    if path.suffix == ".npz":
        save_failed(path, reason, {"stage": stage})
    elif path.suffix == ".json":
        write_json(path, {"failed": True, "stage": stage, "error": str(reason)})
    elif path.suffix == ".png":
        from .figures import failure_figure

        failure_figure(stage, reason, path)
    else:
        with atomic_path(path) as tmp:
            Path(tmp).write_text(f"{stage} failed: {reason}\n", encoding="utf-8")


def check_failed(obj: Mapping, path: str | Path) -> Mapping:
    """``obj`` (a JSON stage output or NPZ meta) unless it records a failure: then raise
    :class:`Failed` naming the file, the stage and its reason."""
    if obj.get("failed") or obj.get("kind") == "ssamb.Failed":
        raise Failed(f"{path}: stage {obj.get('stage', '?')} failed: {obj.get('error', obj.get('reason'))}")
    return obj


def failure_reason(path: str | Path) -> str | None:
    """The reason recorded in a failure marker (NPZ or JSON), or None for a result."""
    path = Path(path)
    meta = read_json(path) if path.suffix == ".json" else load_npz(path)[1]
    if meta.get("failed") or meta.get("kind") == "ssamb.Failed":
        return str(meta.get("error", meta.get("reason")))
    return None


def load_record(path: str | Path) -> tuple[dict, dict]:
    """A simulation record (:func:`ssamb.io.load_npz`), or :class:`Failed` for a failure marker."""
    arrays, meta = load_npz(path)
    check_failed(meta, path)
    return arrays, meta


def load_model(path: str | Path) -> IdentifiedModel:
    """Read a model written by :func:`save_model`.

    Raises
    ------
    Failed
        The file records a failed fit (the message gives its reason).
    DataError
        Not a model file.
    """
    arrays, meta = load_record(path)
    if meta.get("kind") != "ssamb.IdentifiedModel":
        raise DataError(f"{path}: not an identified-model file (kind={meta.get('kind')!r})")
    return _model_from(arrays, meta)


def _model_from(arrays: Mapping, meta: Mapping) -> IdentifiedModel:
    from .identification import IdentifiedModel

    return IdentifiedModel(
        A=np.atleast_2d(arrays["A"]), B=np.atleast_2d(arrays["B"]), C=np.atleast_2d(arrays["C"]),
        D=np.atleast_2d(arrays["D"]), dt=float(meta["dt"]), method=meta["method"],
        input_names=tuple(meta["input_names"]), output_names=tuple(meta["output_names"]),
        affine=bool(meta["affine"]), u_op=np.atleast_1d(arrays["u_op"]),
        y_op=np.atleast_1d(arrays["y_op"]), K=arrays.get("K"), data_hash=meta["data_hash"],
        ss_f=int(meta["ss_f"]), ss_p=int(meta["ss_p"]), info=meta.get("info", {}),
    )


def save_candidates(path: str | Path, subsystem: str, candidates) -> None:
    """Write the candidate models of one subsystem (:class:`ssamb.identification.joint.Candidate`,
    failed ones with their error) to one NPZ: arrays ``c<i>_<A|B|C|D|u_op|y_op|K>`` and a JSON
    list of the settings, errors and model metadata."""
    arrays, items = {}, []
    for i, c in enumerate(candidates):
        item = {"settings": dict(c.settings), "error": c.error, "same_as": c.same_as, "model": None}
        if c.model is not None:
            arrays.update({f"c{i}_{k}": v for k, v in _model_arrays(c.model).items()})
            item["model"] = _model_meta(c.model)
        items.append(item)
    save_npz(path, arrays, {"kind": "ssamb.Candidates", "subsystem": subsystem, "candidates": items})


def load_candidates(path: str | Path) -> list:
    """Read the candidates written by :func:`save_candidates` (DataError if not such a file)."""
    from .identification.joint import Candidate

    arrays, meta = load_record(path)
    if meta.get("kind") != "ssamb.Candidates":
        raise DataError(f"{path}: not a candidate-models file (kind={meta.get('kind')!r})")
    out = []
    for i, item in enumerate(meta["candidates"]):
        model = None
        if item["model"] is not None:
            model = _model_from({k[len(f"c{i}_"):]: v for k, v in arrays.items() if k.startswith(f"c{i}_")},
                                item["model"])
        out.append(Candidate(meta["subsystem"], item["settings"], model, item["error"], item["same_as"]))
    return out


def save_statespace(path: str | Path, sys: control.StateSpace, meta: Mapping | None = None) -> None:
    """Write a named state-space system (NPZ arrays + JSON sidecar with names and dt)."""
    info = {"inputs": list(sys.input_labels), "outputs": list(sys.output_labels),
            "dt": 0.0 if not sys.dt else float(sys.dt), "name": sys.name, **(meta or {})}
    save_npz(path, {"A": np.asarray(sys.A), "B": np.asarray(sys.B), "C": np.asarray(sys.C),
                    "D": np.asarray(sys.D)}, info)


def load_statespace(path: str | Path) -> control.StateSpace:
    """Read a system written by :func:`save_statespace`."""
    arrays, meta = load_record(path)
    dt = meta.get("dt", 0.0) or 0
    import control  # imported where needed: a job that never reads a state-space model does not pay for it

    return control.ss(arrays["A"], arrays["B"], arrays["C"], arrays["D"], dt,
                      inputs=meta["inputs"], outputs=meta["outputs"], name=meta.get("name", "sys"))


def save_weight(path: str | Path, gain: float, zeros_hz, poles_hz, meta: Mapping | None = None) -> None:
    r"""Write an uncertainty weight :math:`W(s) = K \prod(1 + s/\omega_z)/\prod(1 + s/\omega_p)`."""
    save_npz(path, {"gain": np.asarray(float(gain)), "zeros_hz": np.asarray(zeros_hz, float),
                    "poles_hz": np.asarray(poles_hz, float)}, dict(meta or {}))


def load_weight(path: str | Path) -> control.TransferFunction:
    r"""Rebuild :math:`W(s) = K \prod(1 + s/\omega_z)/\prod(1 + s/\omega_p)` from a weight file."""
    arrays, _ = load_record(path)
    import control

    s = control.tf("s")
    w = control.tf([float(arrays["gain"])], [1.0])
    for fz in np.atleast_1d(arrays["zeros_hz"]):
        w = w * (1 + s / (2 * np.pi * float(fz)))
    for fp in np.atleast_1d(arrays["poles_hz"]):
        w = w / (1 + s / (2 * np.pi * float(fp)))
    return w
