"""Close the loop with measured data: calibrate the model's own parameters, find what it still
lacks, name it, add it.

``python -m ssamb closeloop DATA --out DIR`` (:func:`run_closeloop`) walks the chain

1. **replay** (:mod:`.replay`): the model driven by the excitation recorded in the data, with
   the data's logging chain; a prediction is the mean of several replays (the loop's noise
   differs from replay to replay as it does from the rig); the record is split (:mod:`.data`)
   into a fitting and a held-out part;
2. **features** (:mod:`.features`, :mod:`.comparison`): what a replay can be compared with --
   DC, the response at the excited lines, lines the excitation lacks -- each with its noise
   estimated from the data (off-grid bins, period-to-period spread) and from the replays;
3. **calibration** (:mod:`.calibration`, :mod:`.estimate`): the nominal parameters a rig never
   matches exactly, estimated by simulation (MAP with their tolerances as priors), with the
   identifiability of each read off the sensitivity matrix;
4. **residual and signatures** (:mod:`.residual`, :mod:`.spectra`, :mod:`.signatures`): the
   evidence for each library effect in the calibrated model's residual, before any fitting;
5. **effects** (:mod:`.models`, :mod:`.fit`, :mod:`.search`): the leading candidates fitted on
   the calibrated model, judged on the held-out part, added while they explain it; then the
   parameters and effects refitted jointly;
6. **report** (:mod:`.report`, :mod:`.figures`): ``closeloop.json`` and figures.

:func:`analyse` is the pure analysis (arrays in, dictionary out). Where the truth is known (the
acceptance suite, the tests), :mod:`.excess` judges the final model against it: the truth's
held-out advantage beyond what the final model's own parameter uncertainty costs there.
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

__all__ = ["analyse", "comparison_of", "run_closeloop", "write_analysis", "DataError"]


def comparison_of(arrays: Mapping, meta: Mapping, cfg: Mapping, source: str = "data", workers: int = 1,
                  device="amb") -> dict:
    """The analysis's setting before any search: the device, its settings and calibration specs,
    the record, its split, the replayer (close it: ``replay.close()``) and the comparison, its
    noise read about the model the calibration starts from and the lines of the residual set.

    Returns a dict with ``device, settings, specs, notes, record, split, replay, comparison``.
    """
    from ..device import get_device
    from .calibration import bounded, parameter_specs
    from .comparison import Comparison
    from .data import make_split
    from .replay import Replayer
    from .residual import compute_features
    from .settings import settings_from_config

    dev = get_device(device)
    settings = settings_from_config(cfg, dev)
    specs = parameter_specs(cfg, settings.calibration or {})
    dev.validate(arrays, source)
    notes = dev.notes(arrays, meta, cfg)
    rec = dev.record(arrays, meta, cfg, source)
    specs = bounded(specs, dev.calibration_bounds(rec, cfg))
    split = make_split(rec, settings.fit_fraction, settings.discard_s, settings.min_fit_s,
                       settings.min_holdout_s, source)
    replay = Replayer(cfg, rec, workers=int(workers))
    try:
        cmp = Comparison.build(rec, split, replay, range(1, settings.replay_seeds + 1), settings)
        # the noise is read about the model the calibration starts from (the nominal one, unless the
        # device's data imply a start): replays that drop the body are no model of the rig's noise
        at = dev.initial_estimate(rec, cfg) if specs else {}
        cmp.calibrate_noise(at or None)
        ft = compute_features(rec, cmp.fit.frame, dev.views(rec.channels), dev.views(cmp.prediction(at or None)),
                              settings)
        cmp.set_lines(sorted(ln["f_hz"] for ln in ft.lines))
    except BaseException:
        replay.close()
        raise
    return {"device": dev, "settings": settings, "specs": specs, "notes": notes, "record": rec, "split": split,
            "replay": replay, "comparison": cmp}


def _analyse(arrays: Mapping, meta: Mapping, cfg: Mapping, source: str = "data", progress: bool = False,
             workers: int = 1, device="amb"):
    from .report import build_report
    from .search import search

    t0 = time.perf_counter()
    c = comparison_of(arrays, meta, cfg, source, workers, device)
    replay, settings, rec, split = c["replay"], c["settings"], c["record"], c["split"]
    try:
        result = search(c["comparison"], c["specs"], settings, progress=progress)
    finally:
        replay.close()                  # the worker processes
    wall_s = time.perf_counter() - t0
    log.info("%s: %d simulations (%.1f s, %.3f s each); analysis %.1f s", source, replay.n_sims, replay.wall_s,
             replay.wall_s / max(replay.n_sims, 1), wall_s)
    # wall times go to the log only: closeloop.json is byte-reproducible
    report = build_report(rec, split, result, settings, source, {"simulations": replay.n_sims})
    if c["notes"]:
        report["notes"] = list(c["notes"]) + report["notes"]
    return report, {"record": rec, "split": split, "search": result, "comparison": c["comparison"],
                    "settings": settings}


def analyse(arrays: Mapping, meta: Mapping, cfg: Mapping, workers: int = 1, device="amb") -> dict:
    """Analyse measured data against the nominal model of ``cfg``; return ``closeloop.json`` as a dict.

    Parameters
    ----------
    arrays : mapping
        Measured-data columns of the device (for the AMB: the measured-data format), ``fs_hz``
        included.
    meta : mapping
        The data's ``meta`` (the excitation).
    cfg : mapping
        Validated configuration of the nominal model (its ``closeloop`` section, if any, sets
        the analysis; see :class:`ssamb.closeloop.settings.Settings`).
    workers : int
        Processes that run the independent replays (a fit's design, a prediction's seeds); the
        result does not depend on it.
    device : str or ssamb.device.Device
        The device the data come from (:func:`ssamb.device.get_device`; default the AMB).

    Raises
    ------
    ssamb.io.DataError
        Bad data (missing columns, non-finite values, ``fs_hz`` inconsistent with ``t`` or
        with the model, too short to split).
    """
    return _analyse(arrays, meta, cfg, workers=workers, device=device)[0]


def run_closeloop(data_path, out_dir, config=None, progress: bool = True, workers: int = 1, device="amb",
                  force: bool = False) -> dict:
    """Analyse a data file and write ``out_dir/closeloop.json`` and figures.

    Everything is computed and drawn into a fresh temporary directory beside ``out_dir``,
    which then replaces ``out_dir`` whole (:func:`ssamb.io.replace_dir`): bad input (or any
    failure) leaves nothing behind, and ``out_dir`` holds exactly the files of this analysis
    (no figure of an earlier one survives). An existing ``out_dir`` may only hold what an
    analysis writes (``closeloop.json``, ``*.png``); anything else is an error, checked first.

    Parameters
    ----------
    data_path : path
        Measured data in a format of the device (:meth:`ssamb.device.Device.load`; the AMB:
        ``.npz``, or ``.csv`` with a ``.json`` sidecar).
    out_dir : path
        Output directory (created or replaced).
    config : path or mapping, optional
        Configuration file of the device's model (default: the device's own,
        :meth:`ssamb.device.Device.load_config`) or an already loaded configuration.
    progress : bool
        Progress messages on stderr.
    workers : int
        Processes for the independent replays (:func:`analyse`).
    device : str or ssamb.device.Device
        The device the data come from (default the AMB).
    force : bool
        Replace a previous analysis in ``out_dir``; without, a non-empty ``out_dir`` is an error
        (:func:`ssamb.io.check_output_dir`, checked before anything is read).

    Returns
    -------
    dict
        The ``closeloop.json`` content.
    """
    from ..device import get_device
    from ..io import check_output_dir

    out_dir = Path(out_dir)
    check_output_dir(out_dir, _owned, force)
    dev = get_device(device)
    cfg = dict(config) if isinstance(config, Mapping) else dev.load_config(config)
    arrays, meta = dev.load(data_path)
    report, art = _analyse(arrays, meta, cfg, source=str(data_path), progress=progress, workers=workers, device=dev)
    return write_analysis(report, art, out_dir)


def _owned(p: Path) -> bool:
    """A file an analysis writes: ``closeloop.json`` or a figure."""
    return p.is_file() and (p.name == "closeloop.json" or p.suffix == ".png")


def write_analysis(report: dict, art: Mapping, out_dir) -> dict:
    """Write an analysis (:func:`_analyse`'s report and artefacts) to ``out_dir``: the figures
    and ``closeloop.json``, drawn into a fresh temporary directory beside ``out_dir`` that then
    replaces it whole (:func:`ssamb.io.replace_dir`). Returns the report with its ``figures``."""
    from ..io import replace_dir, write_json
    from .figures import make_figures

    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out_dir.parent, prefix=f".{out_dir.name}."))
    try:
        report["figures"] = make_figures(art, report, tmp)
        write_json(tmp / "closeloop.json", report)
        replace_dir(tmp, out_dir, _owned)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return report
