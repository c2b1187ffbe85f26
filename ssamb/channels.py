r"""The signal table: every named signal of the self-sensing AMB and which subsystem reads or
writes it (paper Fig. 3). One place for the names used by identification, closed-loop
assembly, uncertainty, μ, margins and validation.

Signals (SI units; coil order ``ypos, yneg, xpos, xneg`` everywhere)::

    e_x = r_x - x_meas  --PID_x-->  u_x ;  u_x_cmd = u_x + inj_x
    e_y = r_y - y_ss    --PID_y-->  u_y ;  u_y_cmd = u_y + inj_y
    (u_x_cmd, u_y_cmd[, x_meas, y_meas]) --amplifier-->   (i_ypos, i_yneg, i_xpos, i_xneg)
    (i_ypos, i_yneg, i_xpos, i_xneg)     --plant-->       (x_meas, y_meas)
    y_meas (ours) or i_ypos (paper)      --selfsensing--> y_ss

The identified models are affine: their extra constant input is :data:`ONE` (= 1).

Structures
----------
Each subsystem has our default structure and the paper's (config ``identification.<subsystem>``,
key and values in :data:`VARIANTS`):

* plant: 4 currents to (``x_meas``, ``y_meas``), identified on the differential currents
  (``differential``) or on all four (``none``, the paper);
* amplifier: (``u_x_cmd``, ``u_y_cmd``) to the 4 currents (``commands``) or with ``x_meas``,
  ``y_meas`` as further inputs (``full``, the paper's 4-input model);
* selfsensing: ``y_meas`` to ``y_ss`` (``position``) or ``i_ypos`` to ``y_ss`` (``current``,
  the paper's SISO model).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from . import COILS

__all__ = [
    "CURRENTS", "POSITIONS", "ONE", "SUBSYSTEMS", "VARIANTS", "Structure", "structure",
    "CL_INPUTS", "CL_OUTPUTS", "FEEDBACK", "DELTA_CHANNELS", "delta_channels", "etfe_pair",
    "signal", "subsystem_data",
]

#: Coil currents, A (coil order of the architecture).
CURRENTS = tuple("i_" + c for c in COILS)
#: Measured positions, m (eddy-current sensors; ``y_meas`` is for evaluation on the rig).
POSITIONS = ("x_meas", "y_meas")
#: Name of the constant input of an affine model.
ONE = "one"
#: The subsystems identified separately (paper section 3).
SUBSYSTEMS = ("plant", "amplifier", "selfsensing")

#: subsystem -> (config key, our default, the paper's variant)
VARIANTS = {
    "plant": ("input_directions", "differential", "none"),
    "amplifier": ("inputs", "commands", "full"),
    "selfsensing": ("input", "position", "current"),
}

#: Closed-loop inputs (``one`` only when a subsystem is affine) and outputs (Fig. 3).
CL_INPUTS = ("r_x", "r_y", "inj_x", "inj_y", ONE)
CL_OUTPUTS = ("x_meas", "y_meas", "y_ss") + CURRENTS + ("u_x", "u_y")
#: The signal each axis' controller reads (x: eddy-current sensor; y: self-sensing).
FEEDBACK = {"x": "x_meas", "y": "y_ss"}

_COMMANDS = ("u_x_cmd", "u_y_cmd")
_DIFFERENTIAL = np.array([[0.5, -0.5, 0.0, 0.0], [0.0, 0.0, 0.5, -0.5]])


@dataclass(frozen=True)
class Structure:
    """Inputs, outputs and identification input directions of one subsystem variant."""

    subsystem: str
    variant: str
    inputs: tuple
    outputs: tuple
    input_directions: np.ndarray | None = None


def structure(subsystem: str, variant: str | None = None) -> Structure:
    """The :class:`Structure` of ``subsystem`` in ``variant`` (default: ours).

    Raises
    ------
    ValueError
        Unknown subsystem or variant (the message names the config key).
    """
    if subsystem not in VARIANTS:
        raise ValueError(f"subsystem '{subsystem}': must be one of {', '.join(SUBSYSTEMS)}")
    key, ours, paper = VARIANTS[subsystem]
    variant = ours if variant is None else variant
    if variant not in (ours, paper):
        raise ValueError(f"identification.{subsystem}.{key}: '{variant}' ({ours} or {paper})")
    if subsystem == "plant":
        tdir = _DIFFERENTIAL.copy() if variant == "differential" else None
        return Structure(subsystem, variant, CURRENTS, POSITIONS, tdir)
    if subsystem == "amplifier":
        ins = _COMMANDS if variant == "commands" else _COMMANDS + POSITIONS
        return Structure(subsystem, variant, ins, CURRENTS)
    ins = ("y_meas",) if variant == "position" else ("i_ypos",)
    return Structure(subsystem, variant, ins, ("y_ss",))


#: subsystem -> (Delta inputs u, Delta outputs d) of the additive uncertainty (Fig. 6); the
#: self-sensing input is whatever its model reads (:func:`delta_channels`).
DELTA_CHANNELS = {
    "selfsensing": (("i_ypos",), ("y_ss",)),
    "amplifier": (_COMMANDS, CURRENTS),
    "plant": (CURRENTS, POSITIONS),
}


def delta_channels(subsystem: str, selfsensing_input: str = "i_ypos") -> tuple[tuple, tuple]:
    """``(u, d)``: the signals a subsystem's :math:`\\Delta` reads and the outputs it adds to."""
    if subsystem == "selfsensing":
        return (selfsensing_input,), ("y_ss",)
    if subsystem not in DELTA_CHANNELS:
        raise ValueError(f"subsystem '{subsystem}': must be one of {', '.join(SUBSYSTEMS)}")
    return DELTA_CHANNELS[subsystem]


def etfe_pair(subsystem: str, selfsensing_input: str = "y_meas") -> tuple[str, str]:
    """The SISO channel pair whose mismatch ETFE (eq. (6)) is measured for a subsystem, along
    the excited y direction: self-sensing input -> ``y_ss``, ``u_y_cmd`` -> ``i_ypos``,
    ``i_ypos`` -> ``y_meas``."""
    pairs = {"selfsensing": (selfsensing_input, "y_ss"), "amplifier": ("u_y_cmd", "i_ypos"),
             "plant": ("i_ypos", "y_meas")}
    if subsystem not in pairs:
        raise ValueError(f"subsystem '{subsystem}': must be one of {', '.join(SUBSYSTEMS)}")
    return pairs[subsystem]


def signal(arrays: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """Column ``name`` of a data dict, derived signals included
    (``u_x_cmd = u_x + inj_x``, ``u_y_cmd = u_y + inj_y``; a missing injection is zero).

    Raises
    ------
    KeyError
        The column (or the controller output a command derives from) is missing.
    """
    if name in _COMMANDS:
        axis = name[2]
        return np.asarray(arrays["u_" + axis], float) + np.asarray(arrays.get("inj_" + axis, 0.0), float)
    return np.asarray(arrays[name], float)


def subsystem_data(arrays: Mapping[str, np.ndarray], st: Structure) -> tuple[np.ndarray, np.ndarray]:
    """``(u, y)``: the input and output columns of a subsystem structure, as (N, m), (N, l)."""
    u = np.column_stack([signal(arrays, c) for c in st.inputs])
    y = np.column_stack([signal(arrays, c) for c in st.outputs])
    return u, y
