"""Close the loop with measured data: find what the nominal model lacks, name it, add it.

``python -m ssamb closeloop DATA --out DIR`` (:func:`run_closeloop`) walks the chain

1. **replay** (:mod:`.replay`): the nominal nonlinear model driven by the excitation recorded
   in the data; the record is split (:mod:`.data`) into a fitting and a held-out part;
2. **residual** (:mod:`.residual`, :mod:`.spectra`): per-channel residual, noise floor,
   offsets, lines the excitation lacks, excited-line residual and the measured/model ratio of
   the sensor paths, cross-axis coherence, ripple distortion, whiteness;
3. **signatures** (:mod:`.signatures`): the evidence for each library effect, ranked before
   any fitting;
4. **fit** (:mod:`.models`, :mod:`.fit`, :mod:`.search`): the leading candidates fitted by
   simulation on the fitting part, scored on the held-out part, added greedily while the
   held-out error drops significantly, until the residual is consistent with noise;
5. **report** (:mod:`.report`, :mod:`.figures`): ``closeloop.json`` and figures.

:func:`analyse` is the pure analysis (arrays in, dictionary out).
"""
from __future__ import annotations

import logging
import shutil
import tempfile
import time
from pathlib import Path
from typing import Mapping

from ..io import DataError

log = logging.getLogger(__name__)

__all__ = ["analyse", "run_closeloop", "DataError"]


def _analyse(arrays: Mapping, meta: Mapping, cfg: Mapping, source: str = "data", progress: bool = False):
    from ..io import validate_measured
    from .data import make_split, record_from_arrays
    from .replay import Replayer
    from .report import build_report
    from .search import greedy_search
    from .settings import settings_from_config
    from .spectra import make_frame

    t0 = time.perf_counter()
    settings = settings_from_config(cfg)
    validate_measured(arrays, source)
    rec = record_from_arrays(arrays, meta, float(cfg["controller"]["fs_hz"]), source)
    split = make_split(rec, settings.fit_fraction, settings.discard_s, settings.min_fit_s,
                       settings.min_holdout_s, source)
    replay = Replayer(cfg, rec)
    nominal = replay.run()
    fit_frame = make_frame(rec.fs_hz, split.i0, split.i_fit - split.i0, rec.signal, split.n_period, rec.lines_hz)
    hold_frame = make_frame(rec.fs_hz, split.i_fit, split.i_end - split.i_fit, rec.signal, split.n_period, rec.lines_hz)
    search = greedy_search(rec, split, replay, nominal, fit_frame, hold_frame, settings, progress=progress)
    wall_s = time.perf_counter() - t0
    log.info("%s: %d simulations (%.1f s, %.3f s each); analysis %.1f s", source, replay.n_sims, replay.wall_s,
             replay.wall_s / max(replay.n_sims, 1), wall_s)
    # wall times go to the log only: closeloop.json is byte-reproducible
    report = build_report(rec, split, nominal, search, settings, source, {"simulations": replay.n_sims})
    return report, {"record": rec, "split": split, "nominal": nominal, "search": search,
                    "fit_frame": fit_frame, "hold_frame": hold_frame, "settings": settings}


def analyse(arrays: Mapping, meta: Mapping, cfg: Mapping) -> dict:
    """Analyse measured data against the nominal model of ``cfg``; return ``closeloop.json`` as a dict.

    Parameters
    ----------
    arrays : mapping
        Measured-data columns (ARCHITECTURE.md), ``fs_hz`` included.
    meta : mapping
        The data's ``meta`` (the excitation).
    cfg : mapping
        Validated configuration of the nominal model (its ``closeloop`` section, if any, sets
        the analysis; see :class:`ssamb.closeloop.settings.Settings`).

    Raises
    ------
    ssamb.io.DataError
        Bad data (missing columns, non-finite values, ``fs_hz`` inconsistent with ``t`` or
        with the model, too short to split).
    """
    return _analyse(arrays, meta, cfg)[0]


def run_closeloop(data_path, out_dir, config=None, progress: bool = True) -> dict:
    """Analyse a data file and write ``out_dir/closeloop.json`` and figures.

    Everything is computed and drawn into a fresh temporary directory beside ``out_dir``,
    which then replaces ``out_dir`` whole (:func:`ssamb.io.replace_dir`): bad input (or any
    failure) leaves nothing behind, and ``out_dir`` holds exactly the files of this analysis
    (no figure of an earlier one survives). An existing ``out_dir`` may only hold what an
    analysis writes (``closeloop.json``, ``*.png``); anything else is an error, checked first.

    Parameters
    ----------
    data_path : path
        Measured data (``.npz``, or ``.csv`` with a ``.json`` sidecar).
    out_dir : path
        Output directory (created or replaced).
    config : path or mapping, optional
        Configuration file (default: the repository's ``config.yaml``) or an already loaded
        configuration.
    progress : bool
        Progress messages on stderr.

    Returns
    -------
    dict
        The ``closeloop.json`` content.
    """
    from ..config import load_config
    from ..io import check_replaceable, load_measured, replace_dir, write_json
    from .figures import make_figures

    def owned(p: Path) -> bool:
        return p.is_file() and (p.name == "closeloop.json" or p.suffix == ".png")

    out_dir = Path(out_dir)
    check_replaceable(out_dir, owned)
    cfg = dict(config) if isinstance(config, Mapping) else load_config(config)
    arrays, meta = load_measured(data_path)
    report, art = _analyse(arrays, meta, cfg, source=str(data_path), progress=progress)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out_dir.parent, prefix=f".{out_dir.name}."))
    try:
        report["figures"] = make_figures(art, tmp)
        write_json(tmp / "closeloop.json", report)
        replace_dir(tmp, out_dir, owned)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return report
