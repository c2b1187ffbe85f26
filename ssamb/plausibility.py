r"""Plausibility of measured AMB data: impossible values are errors, suspicious ones are notes.

A data file can pass the format's checks (:func:`ssamb.io.validate_measured`: columns present,
finite, uniformly sampled) and still not be what the format says: positions in millimetres,
currents in milliamperes, the x and y columns swapped, a channel that logged a held value. Close
the loop would fit a model to such data and report effects that are artefacts of the file. The
checks here read the data against the nominal configuration of the bearing, before anything is
fitted, and come in two kinds.

**Errors** (:func:`check_measured`, :class:`ssamb.io.DataError`, exit status 2): values the rig
cannot produce, whatever its defects.

* a position beyond twice the airgap (``table1.airgap_m``): the rotor would be inside the
  stator; positions in mm instead of m put a 30 um motion at 0.03 "m", 50 times the airgap;
* a coil current or a controller output beyond three times its limit
  (``amplifier.i_ref_max_a`` and ``table1.i_bias_a + controller.u_max_a`` for the currents,
  ``controller.u_max_a`` for ``u_x``, ``u_y``): currents in mA put the 3 A bias at 3000 "A".

The margins (2 and 3) leave room for a probe's offset, a current's overshoot and a user's config
that differs from the rig; a unit off by 1000 lands far beyond them.

**Notes** (:func:`measured_notes`, listed in ``closeloop.json["notes"]`` and the report): values
a rig can produce, which an analysis should not take at face value. Each names the column and
the computed reason.

* a position channel beyond 1.5 times the backup clearance (``table1.backup_clearance_m``), or
  one that never moves (peak to peak below 1 nm: a held value, a disconnected channel, or a
  unit 1000 times too small), or that is constant;
* nothing excited (every reference and injection constant, and no current injection described in
  ``meta``): levitation at rest, compared by its slow trends and noise spectra alone;
* a channel that sits at its extreme value for at least 0.2 % of the samples (at least 20):
  clipped (a converter's range, an amplifier's or the controller's limit);
* the mean coil current (common mode) of an axis off the bias ``table1.i_bias_a`` by more than a
  factor 2 (a unit, a gain or an offset of the current transducers);
* x and y swapped: a position that follows the other axis' reference better than its own, a
  self-sensing estimate ``y_ss`` closer to ``x_meas`` than to ``y_meas``, or, when the bearing
  carries weight (``weight_share`` > 0; gravity acts on -y), the mean differential current or
  controller output on x rather than y, or the lower magnet ``i_yneg`` carrying it.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

__all__ = ["check_measured", "measured_notes"]

POSITIONS = ("x_meas", "y_meas", "y_ss")
CURRENTS = ("i_ypos", "i_yneg", "i_xpos", "i_xneg")
OUTPUTS = ("u_x", "u_y")
#: margins of the errors (a unit off by 1000 lands far beyond them)
POSITION_ERROR_AIRGAPS = 2.0
LIMIT_ERROR_FACTOR = 3.0
#: thresholds of the notes
POSITION_NOTE_CLEARANCES = 1.5
STILL_M = 1e-9
CLIP_FRACTION = 0.002
CLIP_MIN_SAMPLES = 20
BIAS_FACTOR = 2.0
SWAP_MARGIN = 0.2
SWAP_MIN_CORR = 0.5


def _col(arrays: Mapping, name: str) -> np.ndarray:
    return np.asarray(arrays[name], dtype=float)


def _current_limit(cfg: Mapping) -> float:
    """The largest current the amplifiers are told to carry: the reference clamp, or the bias
    plus the controller's output clamp, whichever is larger (A)."""
    return max(float(cfg["amplifier"]["i_ref_max_a"]),
               float(cfg["table1"]["i_bias_a"]) + float(cfg["controller"]["u_max_a"]))


def check_measured(arrays: Mapping, cfg: Mapping, source: str = "data", meta: Mapping | None = None) -> None:
    """Raise :class:`ssamb.io.DataError` for a value the rig cannot produce (module docstring).

    Data without an excitation (levitation at rest) are no error: close the loop compares their
    slow trends and noise spectra (:func:`measured_notes` says so).

    Parameters
    ----------
    arrays : mapping
        Measured-data columns, already valid in format (:func:`ssamb.io.validate_measured`).
    cfg : mapping
        The nominal configuration of the bearing.
    source : str
        The data file, the first word of the message.
    meta : mapping, optional
        The data's ``meta`` (read for nothing; the device interface passes it).

    Raises
    ------
    ssamb.io.DataError
        One line naming the file, the column, the value and the limit it breaks.
    """
    from .io import DataError

    del meta
    airgap = float(cfg["table1"]["airgap_m"])
    for c in POSITIONS:
        peak = float(np.max(np.abs(_col(arrays, c))))
        if peak > POSITION_ERROR_AIRGAPS * airgap:
            raise DataError(f"{source}: column '{c}' reaches {peak:.4g} m, {peak / airgap:.3g} times the airgap "
                            f"table1.airgap_m = {airgap:g} m: the rotor cannot be there (positions in mm? the "
                            "format's unit is m)")
    limits = [(c, _current_limit(cfg), "amplifier.i_ref_max_a or table1.i_bias_a + controller.u_max_a")
              for c in CURRENTS]
    limits += [(c, float(cfg["controller"]["u_max_a"]), "controller.u_max_a") for c in OUTPUTS]
    for c, lim, key in limits:
        peak = float(np.max(np.abs(_col(arrays, c))))
        if peak > LIMIT_ERROR_FACTOR * lim:
            raise DataError(f"{source}: column '{c}' reaches {peak:.4g} A, {peak / lim:.3g} times the limit "
                            f"{lim:g} A ({key}): no amplifier of this bearing carries it (currents in mA? "
                            "the format's unit is A)")


def _clipped(a: np.ndarray) -> tuple[str, float, float] | None:
    """``(side, value, fraction)`` when ``a`` sits at its maximum or minimum for at least
    :data:`CLIP_FRACTION` of the samples (and :data:`CLIP_MIN_SAMPLES`), else None."""
    n = len(a)
    need = max(CLIP_MIN_SAMPLES, CLIP_FRACTION * n)
    if np.ptp(a) == 0:
        return None
    for side, v in (("maximum", float(np.max(a))), ("minimum", float(np.min(a)))):
        k = int(np.count_nonzero(a == v))
        if k >= need:
            return side, v, k / n
    return None


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    sa, sb = np.std(a), np.std(b)
    if sa == 0 or sb == 0:
        return 0.0
    return float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb))


def _swap_notes(arrays: Mapping, cfg: Mapping) -> list[str]:
    notes = []
    pos = {c: _col(arrays, c) for c in POSITIONS}
    for ax, other in (("x", "y"), ("y", "x")):
        r = _col(arrays, f"r_{ax}")
        if np.ptp(r) == 0:
            continue
        own, cross = _corr(r, pos[f"{ax}_meas"]), _corr(r, pos[f"{other}_meas"])
        if abs(cross) >= SWAP_MIN_CORR and abs(cross) > abs(own) + SWAP_MARGIN:
            notes.append(f"columns '{ax}_meas' and '{other}_meas': the reference r_{ax} is followed by "
                         f"{other}_meas (correlation {cross:.2f}) rather than by {ax}_meas ({own:.2f}): "
                         "x and y swapped?")
    own, cross = _corr(pos["y_ss"], pos["y_meas"]), _corr(pos["y_ss"], pos["x_meas"])
    if abs(cross) >= SWAP_MIN_CORR and abs(cross) > abs(own) + SWAP_MARGIN:
        notes.append(f"column 'y_ss': the self-sensing estimate of y follows x_meas (correlation {cross:.2f}) "
                     f"rather than y_meas ({own:.2f}): x and y swapped?")
    weight_n = float(cfg["weight_share"]) * float(cfg["table1"]["mass_kg"]) * float(cfg["gravity_m_per_s2"])
    if weight_n <= 0:
        return notes
    i0 = float(cfg["table1"]["i_bias_a"])
    d = {ax: 0.5 * float(np.mean(_col(arrays, f"i_{ax}pos") - _col(arrays, f"i_{ax}neg"))) for ax in ("x", "y")}
    u = {ax: float(np.mean(_col(arrays, f"u_{ax}"))) for ax in ("x", "y")}
    small = 0.05 * i0
    if abs(d["x"]) > small and abs(d["x"]) > 3 * abs(d["y"]):
        notes.append(f"columns 'i_xpos', 'i_xneg': the x magnets carry a mean differential current of "
                     f"{d['x']:.3g} A, the y magnets {d['y']:.3g} A, while the weight ({weight_n:.3g} N) acts "
                     "on -y: x and y swapped?")
    elif d["y"] < -small:
        notes.append(f"columns 'i_ypos', 'i_yneg': the lower magnet carries {-2 * d['y']:.3g} A more than the "
                     f"upper one on average, while the weight ({weight_n:.3g} N) acts on -y: i_ypos and i_yneg "
                     "swapped?")
    if abs(u["x"]) > small and abs(u["x"]) > 3 * abs(u["y"]):
        notes.append(f"columns 'u_x', 'u_y': the mean controller output is {u['x']:.3g} A on x and {u['y']:.3g} A "
                     f"on y, while the weight ({weight_n:.3g} N) acts on -y: u_x and u_y swapped?")
    return notes


def measured_notes(arrays: Mapping, meta: Mapping, cfg: Mapping) -> list[str]:
    """Plausibility notes on measured AMB data that are valid but suspicious (module docstring).

    Parameters
    ----------
    arrays : mapping
        Measured-data columns, valid in format (:func:`ssamb.io.validate_measured`) and free of
        impossible values (:func:`check_measured`).
    meta : mapping
        The data's ``meta`` (a current injection it describes is rebuilt from it: the data are
        excited although every logged reference and injection is constant).
    cfg : mapping
        The nominal configuration of the bearing.

    Returns
    -------
    list of str
        One note per finding, each naming the column(s) and the computed reason; empty when
        nothing is suspicious.
    """
    notes = []
    drives = [c for c in ("r_x", "r_y", "inj_x", "inj_y") if c in arrays]
    exc = (meta or {}).get("excitation") or {}
    rebuilt = (isinstance(exc, Mapping) and exc.get("point") == "current" and exc.get("kind") not in (None, "none")
               and not {"inj_x", "inj_y"} <= set(arrays))
    if not rebuilt and all(np.ptp(_col(arrays, c)) == 0 for c in drives):
        notes.append(f"columns {', '.join(repr(c) for c in drives)} are all constant: nothing excites the loop "
                     "(levitation at rest); close the loop compares only slow trends and noise spectra, which "
                     "show fewer effects than the response to a multisine, pulses or a sweep")
    clearance = float(cfg["table1"]["backup_clearance_m"])
    for c in POSITIONS:
        a = _col(arrays, c)
        peak, span = float(np.max(np.abs(a))), float(np.ptp(a))
        if span == 0:
            notes.append(f"column '{c}' is constant ({a[0]:.4g} m): the sensor never moves (a held value or a "
                         "disconnected channel?)")
        elif span < STILL_M:
            notes.append(f"column '{c}' spans {span:.3g} m peak to peak, less than a nanometre: the sensor never "
                         "moves (a held value, or a unit 1000 times too small?)")
        if peak > POSITION_NOTE_CLEARANCES * clearance:
            notes.append(f"column '{c}' reaches {peak:.4g} m, {peak / clearance:.3g} times the backup clearance "
                         f"table1.backup_clearance_m = {clearance:g} m (positions in mm, or an offset?)")
    for c in CURRENTS + OUTPUTS:
        a = _col(arrays, c)
        if np.ptp(a) == 0:
            notes.append(f"column '{c}' is constant ({a[0]:.4g} A): a held value or a disconnected channel?")
    for c in POSITIONS + CURRENTS + OUTPUTS:
        clip = _clipped(_col(arrays, c))
        if clip is not None:
            side, v, frac = clip
            unit = "m" if c in POSITIONS else "A"
            notes.append(f"column '{c}' sits at its {side} {v:.4g} {unit} in {100 * frac:.2g} % of the samples: "
                         "clipped (a converter's range, an amplifier's or the controller's limit)?")
    i0 = float(cfg["table1"]["i_bias_a"])
    for ax in ("x", "y"):
        cm = 0.5 * float(np.mean(_col(arrays, f"i_{ax}pos") + _col(arrays, f"i_{ax}neg")))
        if not i0 / BIAS_FACTOR <= cm <= i0 * BIAS_FACTOR:
            notes.append(f"columns 'i_{ax}pos', 'i_{ax}neg': mean current {cm:.4g} A, the bias table1.i_bias_a is "
                         f"{i0:g} A ({cm / i0:.3g} times): a unit, gain or offset of the current transducers?")
    notes += _swap_notes(arrays, cfg)
    return notes
