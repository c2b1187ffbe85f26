r"""Position controller: two identical decoupled PID controllers (paper Table 1, Fig. 3).

The continuous-time law is

.. math:: C(s) = K_P + \frac{K_I}{s} + \frac{K_D s}{1 + s/\omega_d},

with the Table 1 gains (output in amperes of differential current per metre of position error)
and a derivative low-pass at ``controller.derivative_filter_hz`` (an assumption: the paper does
not state one, and an unfiltered derivative at 83.3 kHz would amplify sensor noise by
``K_D f_s``). It is discretised with the bilinear (Tustin) transform at the controller rate.
The simulator executes :func:`pid_discrete` (in the parallel form of
:func:`pid_kernel_coefficients`, with the output clamp and conditional integration), and the
closed-loop LTI assembly uses the same object, so both stages share one controller.

python-control is imported where a transfer function is built, not with the module: a process
that only simulates (a workflow job, a replay) reads the kernel's coefficients of the
configured controller from :data:`KERNEL_COEFFICIENTS`, which
``tests/test_sim_control.py`` recomputes with python-control bit for bit, and so does not pay for
importing it (about a CPU second, with SciPy's signal and statistics modules and Matplotlib).
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import TYPE_CHECKING, Mapping

import numpy as np

if TYPE_CHECKING:                       # pragma: no cover
    import control

__all__ = ["pid_continuous", "pid_discrete", "pid_kernel_coefficients", "KERNEL_COEFFICIENTS"]

#: :func:`pid_kernel_coefficients` of the configurations the repository ships, keyed on the five
#: numbers that define the PID, ``(K_P, K_I, K_D, derivative_filter_hz, fs_hz)``: what
#: python-control's Tustin discretisation gives, as exact floats
#: (``tests/test_sim_control.py`` checks every entry against it). Any other controller is
#: computed with python-control.
KERNEL_COEFFICIENTS = {
    (20000.0, 700000.0, 38.0, 700.0, 83300.0): (("kp", 20000.000000007363), ("ki_half", 4.201680671957167),
                                                ("a_d", 0.9485581842296774), ("b_d", 162833.92363936774)),
}


def pid_continuous(cfg: Mapping) -> control.TransferFunction:
    """Continuous PID :math:`C(s)` (A/m) from the config."""
    import control

    t1 = cfg["table1"]
    kp, ki, kd = t1["pid_kp_a_per_m"], t1["pid_ki_a_per_m_s"], t1["pid_kd_a_s_per_m"]
    wd = 2 * math.pi * cfg["controller"]["derivative_filter_hz"]
    s = control.tf("s")
    return kp + ki / s + kd * s / (1 + s / wd)


def pid_discrete(cfg: Mapping) -> control.StateSpace:
    """Tustin discretisation of :func:`pid_continuous` at ``controller.fs_hz`` (state-space)."""
    import control

    dt = 1.0 / cfg["controller"]["fs_hz"]
    cd = control.sample_system(control.ss(pid_continuous(cfg)), dt, method="tustin")
    return cd


def pid_kernel_coefficients(cfg: Mapping) -> dict:
    r"""The compiled kernel's form of :func:`pid_discrete` (so that both run one controller).

    The kernel keeps the proportional, integral and derivative parts apart (it integrates
    conditionally when the output clamps), :math:`C(z) = K_P + \tfrac{K_I T}{2}\frac{z+1}{z-1}
    + b_d\frac{z-1}{z-a_d}`. The coefficients are read off :func:`pid_discrete` by partial
    fractions: :math:`a_d` is its pole other than 1, the residue at 1 is :math:`K_I T`, the
    residue at :math:`a_d` is :math:`b_d (a_d - 1)`, and :math:`C(\infty) = K_P + K_I T/2 + b_d`.
    Returns ``{"kp", "ki_half", "a_d", "b_d"}`` (from :data:`KERNEL_COEFFICIENTS` when it holds the
    controller, else computed and cached on the five numbers that define the PID).
    """
    t1, ctl = cfg["table1"], cfg["controller"]
    return dict(_kernel_coefficients(t1["pid_kp_a_per_m"], t1["pid_ki_a_per_m_s"], t1["pid_kd_a_s_per_m"],
                                     ctl["derivative_filter_hz"], ctl["fs_hz"]))


def _kernel_coefficients(kp: float, ki: float, kd: float, f_d: float, fs: float) -> tuple:
    known = KERNEL_COEFFICIENTS.get((kp, ki, kd, f_d, fs))
    return known if known is not None else kernel_coefficients_of_control(kp, ki, kd, f_d, fs)


@lru_cache(maxsize=64)
def kernel_coefficients_of_control(kp: float, ki: float, kd: float, f_d: float, fs: float) -> tuple:
    """The kernel's coefficients of :func:`pid_kernel_coefficients` computed from python-control's
    discretisation (:func:`pid_discrete`), as ``((name, value), ...)``."""
    import control

    cfg = {"table1": {"pid_kp_a_per_m": kp, "pid_ki_a_per_m_s": ki, "pid_kd_a_s_per_m": kd},
           "controller": {"derivative_filter_hz": f_d, "fs_hz": fs}}
    tf = control.ss2tf(pid_discrete(cfg))
    num = np.asarray(tf.num[0][0], float)
    den = np.asarray(tf.den[0][0], float)
    num, den = num / den[0], den / den[0]
    poles = np.roots(den)
    a_d = float(np.real(poles[np.argmax(np.abs(poles - 1.0))]))
    res_1 = np.polyval(num, 1.0) / (1.0 - a_d)
    res_d = np.polyval(num, a_d) / (a_d - 1.0)
    ki_half = res_1 / 2.0
    b_d = res_d / (a_d - 1.0)
    c_inf = num[0] if len(num) == len(den) else 0.0
    return (("kp", float(c_inf - ki_half - b_d)), ("ki_half", float(ki_half)), ("a_d", a_d), ("b_d", float(b_d)))
