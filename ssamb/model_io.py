r"""Model files: identified subsystem models, state-space systems and uncertainty weights.

Each is an NPZ of arrays with a JSON sidecar (:func:`ssamb.io.save_npz`), read back into the
objects the stages work with.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

import control
import numpy as np

from .identification import IdentifiedModel
from .io import DataError, load_npz, save_npz

__all__ = ["FailedFit", "save_failed", "failure_reason", "save_model", "load_model", "save_candidates",
           "load_candidates", "save_statespace", "load_statespace", "save_weight", "load_weight"]

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
        "info": json.loads(json.dumps(model.info, default=lambda o: np.asarray(o).tolist())),
    }


def save_model(path: str | Path, model: IdentifiedModel) -> None:
    """Write ``model`` to ``path`` (.npz arrays) with a JSON sidecar (names, method, hash ...)."""
    save_npz(path, _model_arrays(model), _model_meta(model))


class FailedFit(DataError):
    """A model file records a failed identification (:func:`save_failed`), not a model."""


def save_failed(path: str | Path, reason: str, meta: Mapping | None = None) -> None:
    """Write a *failed-fit* file in place of a model: the rule's output exists, and whoever
    reads it learns that and why the fit failed (:func:`load_model` raises :class:`FailedFit`)."""
    save_npz(path, {}, {"kind": "ssamb.FailedFit", "reason": str(reason), **dict(meta or {})})


def failure_reason(path: str | Path) -> str | None:
    """The reason recorded in a failed-fit file, or None for a model file."""
    _, meta = load_npz(path)
    return meta.get("reason") if meta.get("kind") == "ssamb.FailedFit" else None


def load_model(path: str | Path) -> IdentifiedModel:
    """Read a model written by :func:`save_model`.

    Raises
    ------
    FailedFit
        The file records a failed fit (the message gives its reason).
    DataError
        Not a model file.
    """
    arrays, meta = load_npz(path)
    if meta.get("kind") == "ssamb.FailedFit":
        raise FailedFit(f"{path}: the identification failed: {meta.get('reason')}")
    if meta.get("kind") != "ssamb.IdentifiedModel":
        raise DataError(f"{path}: not an identified-model file (kind={meta.get('kind')!r})")
    return _model_from(arrays, meta)


def _model_from(arrays: Mapping, meta: Mapping) -> IdentifiedModel:
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

    arrays, meta = load_npz(path)
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
    arrays, meta = load_npz(path)
    dt = meta.get("dt", 0.0) or 0
    return control.ss(arrays["A"], arrays["B"], arrays["C"], arrays["D"], dt,
                      inputs=meta["inputs"], outputs=meta["outputs"], name=meta.get("name", "sys"))


def save_weight(path: str | Path, gain: float, zeros_hz, poles_hz, meta: Mapping | None = None) -> None:
    r"""Write an uncertainty weight :math:`W(s) = K \prod(1 + s/\omega_z)/\prod(1 + s/\omega_p)`."""
    save_npz(path, {"gain": np.asarray(float(gain)), "zeros_hz": np.asarray(zeros_hz, float),
                    "poles_hz": np.asarray(poles_hz, float)}, dict(meta or {}))


def load_weight(path: str | Path) -> control.TransferFunction:
    r"""Rebuild :math:`W(s) = K \prod(1 + s/\omega_z)/\prod(1 + s/\omega_p)` from a weight file."""
    arrays, _ = load_npz(path)
    s = control.tf("s")
    w = control.tf([float(arrays["gain"])], [1.0])
    for fz in np.atleast_1d(arrays["zeros_hz"]):
        w = w * (1 + s / (2 * np.pi * float(fz)))
    for fp in np.atleast_1d(arrays["poles_hz"]):
        w = w / (1 + s / (2 * np.pi * float(fp)))
    return w
