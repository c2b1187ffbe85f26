r"""Per-subsystem black-box identification with SIPPY (paper section 3).

Modules: :mod:`.data` (fit metric, checks, excitation), :mod:`.model` (the identified affine
model), :mod:`.subspace` (:func:`identify`), :mod:`.selection` (order scan, method comparison),
:mod:`.joint` (candidates chosen by the assembled loop), :mod:`.sippy_fast` (compiled SIPPY
loops). Model files: :mod:`ssamb.model_io`.

The paper identifies three discrete-time state-space models at the controller rate
(83.3 kHz) from closed-loop data of the nonlinear simulator (Fig. 3):

* **plant**: 4 coil currents :math:`\to` (``x_meas``, ``y_meas``), order 9;
* **amplifier**: (``u_x + inj_x``, ``u_y + inj_y``, ``x_meas``, ``y_meas``) :math:`\to` 4 coil
  currents, order 7;
* **selfsensing**: ``i_ypos`` :math:`\to` ``y_ss``, order 3.

Operating point (no detrending)
-------------------------------
The paper insists that the data must not be detrended: DCM self-sensing depends on the bias
current, and the LTI self-sensing model has to carry the set point (``y_ss`` :math:`\approx 0`
at ``i_ypos`` :math:`\approx` 3.57 A) or the LTI loop delevitates. Every model identified
here is therefore **affine**, written with an extra constant input ``one`` (= 1):

.. math::

    x_{k+1} = A x_k + B u_k + b_1, \qquad y_k = C x_k + D u_k + d_1,

stored as ``B = [B | b_1]`` and ``D = [D | d_1]`` with input names ``(..., "one")``. The
operating point survives in the model: with the inputs held at :math:`u_{op}` the equilibrium
is :math:`x_{op} = (I - A)^{-1}(B u_{op} + b_1)`, :math:`y_{op} = C x_{op} + D u_{op} + d_1`.

SIPPY cannot take the constant column directly (its subspace routines divide every channel by
its standard deviation, which is zero for a constant), so the estimation runs in steps:

1. the operating point :math:`(\bar u, \bar y)`: :math:`\bar u` is the input mean and
   :math:`\bar y` the output equilibrium *consistent with the dynamics* at :math:`\bar u`,
   from a high-order ARX model with an intercept fitted to the raw data
   (:func:`arx_equilibrium`). It is **not** the output mean: the mean differs from the
   equilibrium by the mean of the transients, :math:`O(1/N)`, and that constant left in the
   centred data is an unmodelled disturbance that biases the subspace estimate (measured on
   noise-free data of a known 4th-order system: pole errors of 1e-1 with the mean, 1e-13 with
   the equilibrium);
2. SIPPY's subspace step runs on :math:`(u - \bar u, y - \bar y)` and returns
   :math:`(A, B, C, D, K)`;
3. the affine columns are folded back **exactly**: :math:`b_1 = -B\bar u`,
   :math:`d_1 = \bar y - D\bar u` (the affine model equals the deviation model plus the
   offsets, nothing is thrown away);
4. by default (``refine='auto'``; ``'none'`` skips it) :math:`B, D, b_1, d_1` are re-estimated by linear
   least squares on the **raw, undetrended** data for the fixed :math:`(A, C)` of step 2
   (output error for a stable :math:`A`, the one-step predictor with the Kalman gain
   :math:`K` for an unstable one), the "focus on simulation" of MATLAB's ``n4sid``.

Initial state for validation
----------------------------
:meth:`IdentifiedModel.estimate_x0` solves the linear least-squares problem
:math:`\min_{x_0} \sum_{k<N_0} \|y_k - C A^k x_0 - y^{(0)}_k\|^2` on the first
:math:`N_0` samples (:math:`y^{(0)}`: the response from :math:`x_0 = 0`); ``x0="steady"``
instead starts at the equilibrium for the first input sample held constant.

Validation fit
--------------
:func:`nrmse_fit` is MATLAB ``compare``'s fit, per output channel. For a stable model the fit
is that of the pure simulation (``horizon=None``); an unstable model (the AMB plant is
open-loop unstable) cannot be simulated open loop for half a second, so ``horizon="auto"``
uses the :math:`k`-step-ahead prediction with the model's predictor gain and
:math:`k = \lceil 1/\ln\rho(A) \rceil` (the number of samples over which the fastest unstable
mode grows by a factor e).

Excitation and rank deficiency
------------------------------
The plant's four current inputs are excited almost only in the differential direction (the
injections enter through ``u_x``, ``u_y``; the common mode carries only the constant bias, the
PWM ripple and the position back-coupling). :func:`input_excitation` reports the singular
values of the scaled input matrix; ``input_directions`` (a user-chosen :math:`T`, e.g. the
differential currents) or ``input_rank_tol`` (principal directions) identify the model on
:math:`T u` and expand it back, :math:`B = B_T T`, which gives the minimum-norm model: zero
gain in unexcited directions. The constant part of the common mode is carried by the affine
column either way.

The amplifier's position inputs are harder: in closed loop without an independent excitation
of the rotor, ``x_meas`` and ``y_meas`` are causal functions of the past commands, so only
:math:`(I - G_x P)^{-1} G_u` is identifiable, not the split into command path :math:`G_u` and
position path :math:`G_x`. ``input_excitation(u, hankel_rows=f)`` (stored in ``info`` by
:func:`identify`) exposes it as near-zero singular values of the input block-Hankel matrix.
"""
from __future__ import annotations

from .data import (
    FS_HZ_DEFAULT,
    IOData,
    check_io_data,
    data_hash,
    input_excitation,
    nrmse_fit,
    subsystem_io,
)
from .model import IdentifiedModel, auto_horizon
from .selection import (
    MethodResult,
    OrderScan,
    compare_methods,
    order_scan,
    subspace_singular_values,
)
from .sippy_fast import fast_sippy
from .subspace import METHODS, arx_equilibrium, identify

__all__ = [
    "METHODS", "FS_HZ_DEFAULT", "IOData", "IdentifiedModel", "OrderScan", "MethodResult",
    "nrmse_fit", "data_hash", "check_io_data", "subsystem_io", "input_excitation", "identify",
    "subspace_singular_values", "order_scan", "compare_methods", "auto_horizon", "arx_equilibrium",
    "fast_sippy",
]
