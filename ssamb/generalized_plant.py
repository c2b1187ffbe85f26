r"""Generalized plant of the self-sensing AMB with additive uncertainty (paper Figs. 5-6, eq. (3)).

Each subsystem model :math:`\bar G_k` becomes :math:`\bar G_k + W_k \Delta_k` (eq. (4)): a
disturbance :math:`d_k = W_k \Delta_k u_k` is added to the subsystem's outputs, where
:math:`u_k` are its inputs. Pulling the :math:`\Delta_k` out of the loop (Fig. 5) and closing
it with the controller (lower LFT) leaves

.. math:: N_{11}(s) = \mathrm{diag}(W_k(s) I)\; T_{d \to u}(s),

the transfer from the disturbances :math:`d` to the uncertainty inputs :math:`u`, scaled by the
weights. Stability is robust for all :math:`\|\Delta\|_\infty \le 1` iff
:math:`\sup_\omega \mu_\Delta(N_{11}(j\omega)) < 1`.

Uncertainty cases (dimensionally consistent channel sets, one scalar weight per subsystem):

=============== ====================================== ===================== ============
case            Delta input u (from the loop)          Delta output d        block
=============== ====================================== ===================== ============
selfsensing     the model's input (i_ypos or y_meas)   added to y_ss         [1, 1]
amplifier       u_x_cmd, u_y_cmd                       added to 4 currents   [4, 2]
plant           4 currents                             added to x, y         [2, 4]
all             the three above, block-diagonal                              three blocks
=============== ====================================== ===================== ============

Blocks follow MATLAB's ``mussv`` convention: ``[r, c]`` is an r-by-c full complex block, so
``M`` is (sum c) x (sum r).
"""
from __future__ import annotations

from typing import Mapping

import control
import numpy as np

from .channels import CURRENTS, DELTA_CHANNELS, ONE, delta_channels
from .closed_loop import as_statespace, fig3_loop

__all__ = ["CASES", "case_subsystems", "case_structure", "uncertainty_loop", "n11_channels", "n11_function"]

#: The uncertainty cases: one subsystem, or all three block-diagonally.
CASES = ("selfsensing", "amplifier", "plant", "all")
#: Loop outputs: every candidate Delta input (both self-sensing inputs, commands, currents).
_DELTA_INPUTS = ("i_ypos", "u_x_cmd", "u_y_cmd") + CURRENTS[1:] + ("x_meas", "y_meas")
#: Subsystem outputs that carry a disturbance (each Delta output d).
_DISTURBED = ("x_meas", "y_meas") + CURRENTS + ("y_ss",)


def case_subsystems(case: str) -> tuple[str, ...]:
    """The subsystems whose uncertainty a case contains (block order of N11)."""
    if case == "all":
        return ("selfsensing", "amplifier", "plant")
    if case not in DELTA_CHANNELS:
        raise ValueError(f"uncertainty case '{case}': must be one of {', '.join(CASES)}")
    return (case,)


def case_structure(case: str) -> list[list[int]]:
    """``mussv`` block structure of a case (one full complex block per subsystem)."""
    return [[len(DELTA_CHANNELS[k][1]), len(DELTA_CHANNELS[k][0])] for k in case_subsystems(case)]


def uncertainty_loop(plant, amplifier, selfsensing, pid_x, pid_y) -> control.StateSpace:
    r"""The closed loop of Fig. 3 with additive disturbance inputs at every subsystem output.

    Inputs: ``d_x_meas``, ``d_y_meas``, ``d_i_ypos`` ... ``d_i_xneg``, ``d_y_ss`` (each added to
    the named subsystem output); outputs: every candidate uncertainty input (``i_ypos``,
    ``u_x_cmd``, ``u_y_cmd``, the four currents, the positions). References, injections and the
    affine ``one`` stay open: the transfer functions are about the operating point. Discrete, at
    the models' dt (:func:`ssamb.closed_loop.fig3_loop`).
    """
    loop = fig3_loop(plant, amplifier, selfsensing, pid_x, pid_y, inputs=["d_" + d for d in _DISTURBED],
                     outputs=_DELTA_INPUTS, disturbed=_DISTURBED, name="uncertainty_loop")
    loop.info_ss_input = [c for c in as_statespace(selfsensing).input_labels if c != ONE][0]
    return loop


def n11_channels(loop: control.StateSpace, case: str) -> tuple[list, list, list]:
    """Indices of the Delta inputs u (loop outputs, rows of N11) and of the Delta outputs d
    (loop inputs ``d_*``, columns) of a case, in block order, and the subsystem of each row."""
    ss_in = getattr(loop, "info_ss_input", "i_ypos")
    rows, cols, wrow = [], [], []
    for k in case_subsystems(case):
        u, d = delta_channels(k, ss_in)
        rows += list(u)
        cols += ["d_" + c for c in d]
        wrow += [k] * len(u)
    ri = [list(loop.output_labels).index(r) for r in rows]
    ci = [list(loop.input_labels).index(c) for c in cols]
    return ri, ci, wrow


def n11_function(loop: control.StateSpace, weights: Mapping[str, control.LTI], case: str,
                 scale: float = 1.0):
    r"""Callable ``f(hz) -> N11(j 2 pi hz)`` for a case (complex matrix, mussv shape).

    ``loop`` is :func:`uncertainty_loop` (discrete, evaluated at :math:`z = e^{j\omega T}`) or its
    continuous equivalent (evaluated at :math:`s = j\omega`); the weights are continuous.
    Rows: Delta inputs u in block order; columns: Delta outputs d in block order.
    """
    ri, ci, wrow = n11_channels(loop, case)
    missing = [k for k in dict.fromkeys(wrow) if k not in weights]
    if missing:
        raise ValueError(f"no uncertainty weight for subsystem '{missing[0]}'")
    dt = loop.dt

    def f(hz: float) -> np.ndarray:
        w = 2 * np.pi * hz
        s = 1j * w
        arg = np.exp(s * dt) if dt else s
        T = np.asarray(loop(arg)).reshape(len(loop.output_labels), len(loop.input_labels))
        T = T[np.ix_(ri, ci)]
        wv = np.array([complex(np.squeeze(weights[k](s))) for k in wrow])
        return scale * wv[:, None] * T

    return f
