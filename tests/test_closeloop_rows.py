"""Close the loop on the experiments of issue 23's table, as a user's rig runs them: the
identification's current pulses, a multisine on one axis or both, each with the effects the issue
names. The rig data come from a scenario (the rig's own calibration noise, logging noise); the
analysis sees only the data; the truth must be found within its standard errors (or a practical
tolerance), and the oracle -- the truth replayed exactly as the final model is -- must not beat the
final model on the held-out part by more than the noise allows (the held-out improvement test an
effect passes to be accepted).

Short records keep them cheap: pulses 0.6 s, multisines of 5 lines (5-25 Hz) over 0.8 s, four
replays per prediction.
"""
from __future__ import annotations

import math

import pytest
from scipy import stats

from ssamb.config import load_config

pytestmark = pytest.mark.slow


def _z_crit() -> float:
    return float(stats.norm.isf(load_config()["closeloop"]["alpha_accept"]))


def _delays(rep: dict) -> dict:
    """Reported sensor delays per axis: ``axis -> (value, standard error)``."""
    out = {}
    for e in rep["effects"]:
        if e["name"] == "sensor_delay":
            per = e.get("per_axis") or {e["params"]["axis"]: {"delay_s": e["params"]["delay_s"],
                                                              "se": e["uncertainty"]["delay_s"]}}
            out.update({a: (d["delay_s"], d["se"]) for a, d in per.items()})
    return out


def _near(value: float, se: float, truth: float, tol: float) -> bool:
    return abs(value - truth) <= max(3 * se, tol)


def test_row1_static_load_on_current_pulses(row1):
    """Row 1: the identification's current pulses on a rig with an 8 N load on x: the load is found
    (its DC offset of the x coil currents), nothing else."""
    rep = row1["report"]
    assert [e["name"] for e in rep["effects"]] == ["static_load"], rep["summary"]
    e = rep["effects"][0]
    assert _near(e["params"]["fx_n"], e["uncertainty"]["fx_n"], 8.0, 0.8), e


def _check_delay(rep: dict) -> None:
    """Rows 2 and 3: the 37 us delay is found on every axis it is reported on (the logged
    controller outputs at the PWM's aliased lines pin it), within its standard errors; an axis the
    data determine poorly is reported with a large standard error or not at all (the x probe does
    not see the PWM's ripple: there a delay one whole controller sample away can fit as well, and
    the reported error spans it)."""
    assert {e["name"] for e in rep["effects"]} == {"sensor_delay"}, rep["summary"]
    d = _delays(rep)
    assert "y" in d, d
    for ax, (v, se) in d.items():
        assert _near(v, se, 37e-6, 1e-6), (ax, v, se)


def test_row2_sensor_delay_with_y_excited(row2):
    """Row 2: a 37 us sensor delay on both axes, a 100 um multisine on y only (:func:`_check_delay`)."""
    _check_delay(row2["report"])


def test_row3_sensor_delay_with_both_axes_excited(row3):
    """Row 3: the same rig, a multisine on both axes (:func:`_check_delay`)."""
    _check_delay(row3["report"])


def _check_delay_and_load(rep: dict) -> None:
    """Both effects of :data:`rowcases.DELAY_AND_LOAD` found within their standard errors (the load
    not absorbed by the rotor mass, airgap and turns; kept beside the larger delay), nothing else."""
    assert {e["name"] for e in rep["effects"]} == {"sensor_delay", "static_load"}, rep["summary"]
    d = _delays(rep)
    assert "y" in d and _near(*d["y"], 15e-6, 1e-6), d
    if "x" in d:
        assert _near(*d["x"], 0.0, 1e-6), d
    load = next(e for e in rep["effects"] if e["name"] == "static_load")
    assert _near(load["params"]["fy_n"], load["uncertainty"]["fy_n"], -4.0, 0.4), load
    assert math.isclose(load["params"]["fx_n"], 0.0, abs_tol=max(3 * load["uncertainty"]["fx_n"], 0.4)), load


ROW4 = ("the delay is found (14.97 +- 0.16 us), the load is not: its candidate improves the held-out part by z 1.8, "
        "the residual is consistent with noise once the delay is in, and the truth with the load predicts the "
        "held-out part no better than the final model without it (oracle z 0.7): judged with the predictions' own "
        "noise, this record does not show the load")


@pytest.mark.xfail(strict=True, reason=ROW4)
def test_row4_a_load_beside_a_delay_with_y_excited(row4):
    """Row 4: a 15 us y sensor delay and a -4 N y load, a multisine on y only: both found
    (:func:`_check_delay_and_load`)."""
    _check_delay_and_load(row4["report"])


def test_row5_a_load_beside_a_delay_with_both_axes_excited(row5):
    """Row 5: the same rig, a multisine on both axes: both found (:func:`_check_delay_and_load`;
    the format tests read this analysis too)."""
    _check_delay_and_load(row5["report"])


def _oracle(r: dict) -> None:
    assert r["oracle_z"] <= _z_crit(), r["oracle_z"]


def test_row1_oracle(row1):
    """Row 1's oracle (module docstring)."""
    _oracle(row1)


def test_row2_oracle(row2):
    """Row 2's oracle (module docstring)."""
    _oracle(row2)


def test_row3_oracle(row3):
    """Row 3's oracle (module docstring)."""
    _oracle(row3)


def test_row4_oracle(row4):
    """Row 4's oracle (module docstring)."""
    _oracle(row4)


def test_row5_oracle(row5):
    """Row 5's oracle (module docstring)."""
    _oracle(row5)
