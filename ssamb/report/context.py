"""What every report section reads: the run's results folder, its ``summary.json`` and config."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from ..config import load_config
from ..io import read_json

__all__ = ["Context", "load_context", "experiment"]


@dataclass(frozen=True)
class Context:
    """Inputs of the report sections.

    Attributes
    ----------
    results : Path
        The run's results folder (``results/``).
    summary : dict
        Its ``summary.json``.
    config : dict
        The validated config of the run (figures in the report text come from it).
    config_path : Path
        The config file (its comments are the reasons in the parameter table).
    closeloop_dir : Path or None
        The analysis folder of the default close-the-loop data set.
    study : dict or None
        The assumption study (``results/study/study.json``), when the report holds it.
    ensemble : dict or None
        The noise ensembles (``results/ensemble/ensemble.json``), when the report holds them.
    """

    results: Path
    summary: Mapping[str, Any]
    config: Mapping[str, Any]
    config_path: Path
    closeloop_dir: Path | None = None
    study: Mapping[str, Any] | None = None
    ensemble: Mapping[str, Any] | None = None

    def path(self, *parts: str) -> Path:
        return self.results.joinpath(*parts)


def load_context(results: str | Path, config_path: str | Path, closeloop_dir: str | Path | None = None,
                 study_json: str | Path | None = None, ensemble_json: str | Path | None = None) -> Context:
    """The :class:`Context` of a results folder (``summary.json`` must exist)."""
    results = Path(results).resolve()
    return Context(results, read_json(results / "summary.json"), load_config(config_path),
                   Path(config_path).resolve(), None if closeloop_dir is None else Path(closeloop_dir).resolve(),
                   None if study_json is None else read_json(study_json),
                   None if ensemble_json is None else read_json(ensemble_json))


def experiment(ctx: Context, key: str) -> Mapping[str, Any]:
    """The excitation of the experiment named at a dotted config key (e.g.
    ``uncertainty.experiment``) or of the experiment itself (e.g. ``sweep``)."""
    node: Any = ctx.config
    for k in key.split("."):
        node = node[k]
    name = node if isinstance(node, str) else key
    return ctx.config["experiments"][name]["excitation"]
