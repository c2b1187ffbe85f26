"""The experiments of issue 23's table as rig scenarios, and their analysis with the oracle
(tests/test_closeloop_rows.py; row 5's analysis, written as the command line writes it, is also
the close-the-loop output the format tests read: tests/conftest.py ``row5``)."""
from __future__ import annotations

from pathlib import Path

import yaml

from ssamb.config import get, load_config
from ssamb.rig import effective_truth, load_scenario, rig_data

REPO = Path(__file__).resolve().parent.parent
NOISE = {"position_m": 3.0e-8, "current_a": 3.0e-4, "seed": 11}
#: replays averaged into a prediction in the rows' analyses
REPLAY_SEEDS = 4
PULSES = {"kind": "pulses", "point": "current", "axis": "both", "amplitude_a": 0.3, "min_width_s": 2.0e-4,
          "max_width_s": 4.0e-3, "seed": 5}
#: rows 4 and 5: a 15 us y sensor delay beside a -4 N y static load
DELAY_AND_LOAD = [{"name": "sensor_delay", "axis": "y", "delay_s": 15e-6},
                  {"name": "static_load", "fx_n": 0.0, "fy_n": -4.0}]


def row(name: str) -> tuple:
    """Row ``name`` (``row1`` ... ``row5``) of issue 23's table: ``(experiment, effects, duration_s)``."""
    delay37 = [{"name": "sensor_delay", "axis": "both", "delay_s": 37e-6}]
    return {"row1": (PULSES, [{"name": "static_load", "fx_n": 8.0, "fy_n": 0.0}], 0.6),
            "row2": (multisine("y"), delay37, None), "row3": (multisine("both"), delay37, None),
            "row4": (multisine("y"), DELAY_AND_LOAD, None), "row5": (multisine("both"), DELAY_AND_LOAD, None)}[name]


def multisine(axis: str) -> dict:
    """A 100 um multisine of 5 lines (5-25 Hz) over four 0.2 s periods on ``axis`` (y or both)."""
    return {"kind": "multisine", "point": "position", "axis": axis, "amplitude_m": 1.0e-4, "f_min_hz": 5.0,
            "f_max_hz": 25.0, "f_resolution_hz": 5.0, "periods": 4, "seed": 4}


def rows_config() -> dict:
    """The repository's config with :data:`REPLAY_SEEDS` replays per prediction."""
    cfg = load_config()
    return {**cfg, "closeloop": {**cfg["closeloop"], "replay_seeds": REPLAY_SEEDS}}


def analysed(tmp: Path, experiment: dict, effects: list, duration_s: float | None = None, workers: int = 1,
             out: Path | None = None):
    """Rig data of the scenario, the analysis and the oracle: ``(report, oracle z)``; with ``out``
    the report and figures are written there as :func:`ssamb.closeloop.run_closeloop` writes them.

    The oracle replays the truth as the model can see it (the nominal parameters with the rig's
    own DCM calibration, :func:`ssamb.rig.effective_truth`, and the true effects) exactly as the
    final model is replayed, and scores it against the final model on the held-out part
    (:func:`ssamb.closeloop.fit.holdout_score`: z > 0 when the truth does better)."""
    from ssamb.closeloop import _analyse, write_analysis
    from ssamb.closeloop.fit import Base, holdout_score

    cfg = rows_config()
    sc = {"config": str(REPO / "config.yaml"), "experiment": experiment, "effects": effects, "noise": NOISE}
    if duration_s is not None:
        sc["duration_s"] = duration_s
    p = tmp / "rig.yaml"
    p.write_text(yaml.safe_dump(sc))
    scenario = load_scenario(p)
    arrays, meta = rig_data(scenario)
    rep, art = _analyse(arrays, meta, cfg, workers=workers)
    truth = effective_truth(scenario, {k: 0.0 for k in cfg["closeloop"]["calibration"]})
    ov = {k: get(cfg, k) * (1 + d) if get(cfg, k) != 0 else d for k, d in truth.items()}
    cmp, search = art["comparison"], art["search"]
    try:
        pred = cmp.prediction(ov, effects)
        hs = holdout_score(cmp, Base(search.overrides, search.effects, search.final), pred, ov, effects, 0,
                           art["settings"])
    finally:
        cmp.replay.close()
    if out is not None:
        write_analysis(rep, art, out)
    return rep, hs["z"]
