r"""Position controller: two identical decoupled PID controllers (paper Table 1, Fig. 3).

The continuous-time law is

.. math:: C(s) = K_P + \frac{K_I}{s} + \frac{K_D s}{1 + s/\omega_d},

with the Table 1 gains (output in amperes of differential current per metre of position error)
and a derivative low-pass at ``controller.derivative_filter_hz`` (an assumption: the paper does
not state one, and an unfiltered derivative at 83.3 kHz would amplify sensor noise by
``K_D f_s``). It is discretised with the bilinear (Tustin) transform at the controller rate.
The simulator executes exactly the discrete state-space returned by :func:`pid_discrete`, and
the closed-loop LTI assembly uses the same object, so both stages share one controller.
"""
from __future__ import annotations

import math
from typing import Mapping

import control
import numpy as np

__all__ = ["pid_continuous", "pid_discrete", "pid_matrices"]


def pid_continuous(cfg: Mapping) -> control.TransferFunction:
    """Continuous PID :math:`C(s)` (A/m) from the config."""
    t1 = cfg["table1"]
    kp, ki, kd = t1["pid_kp_a_per_m"], t1["pid_ki_a_per_m_s"], t1["pid_kd_a_s_per_m"]
    wd = 2 * math.pi * cfg["controller"]["derivative_filter_hz"]
    s = control.tf("s")
    return kp + ki / s + kd * s / (1 + s / wd)


def pid_discrete(cfg: Mapping) -> control.StateSpace:
    """Tustin discretisation of :func:`pid_continuous` at ``controller.fs_hz`` (state-space)."""
    dt = 1.0 / cfg["controller"]["fs_hz"]
    cd = control.sample_system(control.ss(pid_continuous(cfg)), dt, method="tustin")
    return cd


def pid_matrices(cfg: Mapping) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C, D)`` of :func:`pid_discrete` as float arrays (for the compiled kernel)."""
    sys = pid_discrete(cfg)
    return (np.asarray(sys.A, float), np.asarray(sys.B, float).ravel(),
            np.asarray(sys.C, float).ravel(), float(np.asarray(sys.D).item()))
