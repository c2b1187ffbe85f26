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

=============== ====================================== =================== ==========
case            Delta input u (from the loop)           Delta output d        block
=============== ====================================== =================== ==========
selfsensing     the model's input (i_ypos or y_meas)    added to y_ss          [1, 1]
amplifier       u_x_cmd, u_y_cmd                        added to 4 currents    [4, 2]
plant           4 currents                              added to x, y          [2, 4]
all             the three above, block-diagonal                                 three blocks
=============== ====================================== =================== ==========

Blocks follow MATLAB's ``mussv`` convention: ``[r, c]`` is an r-by-c full complex block, so
``M`` is (sum c) x (sum r).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Mapping

import control
import numpy as np

from .ident import CURRENTS
from .loop import as_statespace

__all__ = ["CASES", "CASE_CHANNELS", "case_channels", "uncertainty_loop", "case_structure", "n11_function"]

#: subsystem -> (Delta inputs u, Delta outputs d (names of the signals d is added to), block)
CASE_CHANNELS = {
    "selfsensing": (("i_ypos",), ("y_ss",)),
    "amplifier": (("u_x_cmd", "u_y_cmd"), CURRENTS),
    "plant": (CURRENTS, ("x_meas", "y_meas")),
}
CASES = ("selfsensing", "amplifier", "plant", "all")


def _subsystems_for(case: str) -> tuple[str, ...]:
    if case == "all":
        return ("selfsensing", "amplifier", "plant")
    if case not in CASE_CHANNELS:
        raise ValueError(f"uncertainty case '{case}': must be one of {', '.join(CASES)}")
    return (case,)


def case_structure(case: str) -> list[list[int]]:
    """``mussv`` block structure of a case (one full complex block per subsystem)."""
    return [[len(CASE_CHANNELS[k][1]), len(CASE_CHANNELS[k][0])] for k in _subsystems_for(case)]


def case_channels(loop: control.StateSpace) -> dict:
    """Channel sets of the uncertainty cases for the models in ``loop`` (see the table above;
    the self-sensing Delta input is whatever the self-sensing model reads)."""
    ss_in = loop.info_ss_input if hasattr(loop, "info_ss_input") else "i_ypos"
    out = dict(CASE_CHANNELS)
    out["selfsensing"] = ((ss_in,), ("y_ss",))
    return out


def uncertainty_loop(plant, amplifier, selfsensing, pid_x, pid_y) -> control.StateSpace:
    r"""The closed loop of Fig. 3 with additive disturbance inputs at every subsystem output.

    Inputs: ``d_y_ss``, ``d_i_ypos`` ... ``d_i_xneg``, ``d_x_meas``, ``d_y_meas`` (each added to
    the named subsystem output); outputs: every candidate uncertainty input (``i_ypos``,
    ``u_x_cmd``, ``u_y_cmd``, the four currents). The affine ``one`` input is left out: the
    transfer functions are about the operating point. Discrete, at the models' dt.
    """
    P = as_statespace(plant, name="plant")
    G = as_statespace(amplifier, name="amplifier")
    S = as_statespace(selfsensing, name="selfsensing")
    Cx = as_statespace(pid_x, inputs=["e_x"], outputs=["u_x"], name="pid_x")
    Cy = as_statespace(pid_y, inputs=["e_y"], outputs=["u_y"], name="pid_y")
    dt = float(P.dt)

    def renamed(sys, outs_nom):
        return control.ss(sys.A, sys.B, sys.C, sys.D, dt, inputs=list(sys.input_labels),
                          outputs=[o + "_nom" for o in outs_nom], name=sys.name)

    blocks = [renamed(P, P.output_labels), renamed(G, G.output_labels), renamed(S, S.output_labels),
              control.ss(Cx.A, Cx.B, Cx.C, Cx.D, dt, inputs=["e_x"], outputs=["u_x"], name="pid_x"),
              control.ss(Cy.A, Cy.B, Cy.C, Cy.D, dt, inputs=["e_y"], outputs=["u_y"], name="pid_y")]
    d_inputs = []
    for sig in list(P.output_labels) + list(G.output_labels) + list(S.output_labels):
        blocks.append(control.summing_junction(inputs=[sig + "_nom", "d_" + sig], output=sig, dt=dt,
                                               name="add_" + sig))
        d_inputs.append("d_" + sig)
    blocks += [
        control.summing_junction(inputs=["-x_meas"], output="e_x", dt=dt, name="sum_ex"),
        control.summing_junction(inputs=["-y_ss"], output="e_y", dt=dt, name="sum_ey"),
        control.summing_junction(inputs=["u_x"], output="u_x_cmd", dt=dt, name="sum_ux"),
        control.summing_junction(inputs=["u_y"], output="u_y_cmd", dt=dt, name="sum_uy"),
    ]
    outs = ["i_ypos", "u_x_cmd", "u_y_cmd"] + [c for c in CURRENTS if c != "i_ypos"] + ["x_meas", "y_meas"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # the affine input 'one' stays unconnected (zero): deviation model
        sys = control.interconnect(blocks, inplist=d_inputs, inputs=d_inputs, outlist=outs, outputs=outs,
                                   name="uncertainty_loop")
    loop = control.ss(sys.A, sys.B, sys.C, sys.D, dt, inputs=d_inputs, outputs=outs, name=sys.name)
    loop.info_ss_input = [c for c in S.input_labels if c != "one"][0]
    return loop


def n11_function(loop: control.StateSpace, weights: Mapping[str, control.LTI], case: str,
                 scale: float = 1.0):
    r"""Callable ``f(hz) -> N11(j 2 pi hz)`` for a case (complex matrix, mussv shape).

    ``loop`` is :func:`uncertainty_loop` (discrete, evaluated at :math:`z = e^{j\omega T}`) or its
    continuous equivalent (evaluated at :math:`s = j\omega`); the weights are continuous.
    Rows: Delta inputs u in block order; columns: Delta outputs d in block order.
    """
    subs = _subsystems_for(case)
    channels = case_channels(loop)
    rows, cols, wrow = [], [], []
    for k in subs:
        u, d = channels[k]
        if k not in weights:
            raise ValueError(f"no uncertainty weight for subsystem '{k}'")
        rows += list(u)
        cols += ["d_" + c for c in d]
        wrow += [k] * len(u)
    ri = [list(loop.output_labels).index(r) for r in rows]
    ci = [list(loop.input_labels).index(c) for c in cols]
    dt = loop.dt

    def f(hz: float) -> np.ndarray:
        w = 2 * np.pi * hz
        s = 1j * w
        arg = np.exp(s * dt) if dt else s
        T = np.asarray(loop(arg))
        if T.ndim == 1:
            T = T.reshape(len(loop.output_labels), len(loop.input_labels))
        T = T[np.ix_(ri, ci)]
        wv = np.array([complex(np.squeeze(weights[k](s))) for k in wrow])
        return scale * wv[:, None] * T

    return f
