r"""Reluctance-network magnetics of one electromagnet (compiled with numba).

Each electromagnet (ypos, yneg, xpos, xneg) is a series magnetic circuit: two airgaps that move
with the rotor and an iron path (pole legs, back-iron arc, journal arc) with relative
permeability :math:`\mu_r` (paper section 2.2, reluctance network model [25]). The flux
:math:`\Phi` through the circuit is the state. The magnetomotive force the circuit needs is

.. math::

    \mathcal{F}_m(\Phi, \xi) = \Phi \frac{G(\xi)}{\mu_0 A_p}
        + \sum_s l_s H_{an}(\Phi/A_s) + l_{fe} H_{hy}(\Phi/A_p; z),

with :math:`G = 2(g_0 - \xi\cos\alpha)` the two gaps in series.

Saturation (switchable) -- a smooth anhysteretic curve without singularity,

.. math:: H_{an}(B) = \frac{B}{\mu_0\mu_r}\left(1 + s\,(|B|/B_k)^p\right),

whose permeability halves at the knee :math:`B_k` and falls steeply above it (s = 0 turns
saturation off).

Hysteresis (switchable) -- a Prandtl-Ishlinskii operator: K play operators of widths
:math:`r_k = r_{max} k/K` acting on the pole flux density with equal weights :math:`H_c/K`,

.. math:: z_k \leftarrow \min(\max(z_k, B - r_k), B + r_k), \qquad
          H_{hy} = \sum_k \frac{H_c}{K} \frac{B - z_k}{r_k},

so that a large loop has coercivity :math:`H_c` and positive area (energy loss), and minor
loops (PWM ripple) are thinner. It is applied over the whole iron length (a simplification:
the pole legs carry the largest flux density).

Eddy currents (switchable) -- the coil must also supply the eddy MMF of the laminations,
:math:`N i = \mathcal F_m(\Phi) + \mathcal F_{eddy}`, with the coil equation
:math:`v = R i + N\dot\Phi` (Faraday). The default model is the lamination diffusion impedance as
a fitted ladder of lagged fluxes (:mod:`ssamb.sim.eddy`); the variant ``shorted_turn`` is one
short-circuited turn of conductance :math:`g_e`, :math:`\mathcal F_{eddy} = g_e\dot\Phi`, for
which :math:`\dot\Phi = (N v - R \mathcal F_m)/(N^2 + g_e R)` and
:math:`i = (g_e v + N\mathcal F_m)/(g_e R + N^2)`. The kernel (:mod:`ssamb.sim.kernel`)
integrates both.

Force -- Maxwell stress on both pole faces, projected on the magnet axis,
:math:`F = 2 \frac{B^2 A_p}{2\mu_0}\cos\alpha = \Phi^2\cos\alpha/(\mu_0 A_p)`.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from .params import (MU0, P_AP, P_COSA, P_FE_C1, P_FE_C2, P_G0, P_GAPK, P_HC, P_HYST,
                     P_HYST_DF, P_INV_AP, P_INV_PHIK, P_LFE, P_N,
                     P_NPLAY, P_PEXP, P_PLAY_INVR0, P_PLAY_R0, P_SAT)

__all__ = ["mmf_anhysteretic", "mmf", "mmf_update", "flux_from_current", "force_from_flux",
           "play_update", "gap_sum", "static_force", "MAX_PLAY"]

MAX_PLAY = 16

# Per-sample helpers take arrays but never allocate. Compiled without the numba runtime (NRT),
# their array arguments are not reference-counted on every call (two atomic operations per
# array argument and call: ~40 % of the kernel time otherwise). ``_nrt`` is a private numba
# option (numba compiles its own helpers with it); without it the code stays correct, only slower.
NO_NRT = {"_nrt": False} if hasattr(nb.core.options.DefaultOptions, "_nrt") else {}
# Floating-point liberties of the compiled simulator: fused multiply-add only. With all of
# numba's fastmath flags (``fastmath=FASTMATH``: also reassociation, no NaN/inf, approximate
# functions) the kernel compiled in the running process and the same kernel loaded from numba's
# cache gave different bits on 7 of 12 randomized rigs (hashes of a rig's data and two replays,
# ``NUMBA_CACHE_DIR`` fresh, then loaded), and the self-sensed loop grows round-off into a
# different noise realisation: the same analysis took 1591 or 1893 simulations depending on the
# cache. With ``contract`` alone: 12 of 12 identical, and no slower (71.1 ms per replay of
# 1.4 s against 71.6 ms; no flags at all: 75.8 ms, and without ``contract`` 1 of 12 differed).
FASTMATH = {"contract"}
# numba's on-disk cache (cache=True) is keyed on the content of this file only: after changing
# params.py (the P_* layout) or a compiled helper imported from another module, change this
# file too (or clear __pycache__), or stale machine code with old constants is reused.


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def _ipow(x, n):
    """``x**n`` for an integer ``n >= 0`` by repeated squaring (4 multiplications for n = 10)."""
    r = 1.0
    while n > 0:
        if n & 1:
            r *= x
        x *= x
        n >>= 1
    return r


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def mmf_anhysteretic(phi, gsum, p):
    r"""Gap and anhysteretic iron part of the MMF and its derivative, ``(F, dF/dphi)``.

    All iron sections carry the same flux, so with :math:`q = (|\Phi|/(A_p B_k))^p` (the pole
    flux density relative to the knee) one power serves all of them:

    .. math:: \Phi\frac{G}{\mu_0 A_p} + \sum_s l_s H_{an}(\Phi/A_s) = \Phi\,(\frac{G}{\mu_0 A_p} + c_1 + c_2 q),
              \qquad c_1 = \sum_s \frac{l_s}{\mu_0\mu_r A_s}, \quad
              c_2 = \sum_s \frac{l_s}{\mu_0\mu_r A_s}\Big(\frac{A_p}{A_s}\Big)^p,

    (``P_FE_C1``, ``P_FE_C2`` precomputed by :meth:`~ssamb.sim.params.AMBParams.pack`), and
    :math:`dF/d\Phi = G/(\mu_0 A_p) + c_1 + (p+1) c_2 q`.
    """
    g = gsum * p[P_GAPK] + p[P_FE_C1]
    if p[P_SAT] > 0.0:
        c2q = p[P_FE_C2] * _ipow(abs(phi) * p[P_INV_PHIK], int(p[P_PEXP]))
        return phi * (g + c2q), g + (p[P_PEXP] + 1.0) * c2q
    return phi * g, g


@nb.njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def mmf(phi, gsum, z, p):
    """MMF (A-turns) needed to carry flux ``phi`` (Wb) through gaps ``gsum`` (m, both in series).

    ``z`` holds this magnet's play-operator states (read only). Returns ``(F, dF/dphi)``.
    """
    f, df = mmf_anhysteretic(phi, gsum, p)
    if p[P_HYST] > 0.0:
        iap = p[P_INV_AP]
        b = phi * iap
        n = int(p[P_NPLAY])
        lw = p[P_LFE] * p[P_HC] / n
        for k in range(n):
            r = p[P_PLAY_R0 + k]
            ir = p[P_PLAY_INVR0 + k]
            zk = z[k]
            if zk < b - r:
                zk = b - r
            elif zk > b + r:
                zk = b + r
            else:               # elastic (reversible) part of the play
                df += lw * ir * iap
            f += lw * (b - zk) * ir
    return f, df


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH, **NO_NRT)
def mmf_update(phi, gsum, z, j, p):
    r""":func:`play_update` followed by :func:`mmf` in one pass over the play operators.

    After the update every play operator is in its elastic range, :math:`|B - z_k| \le r_k`,
    so the hysteresis adds the constant slope :math:`\sum_k l_{fe} H_c/(K r_k A_p)`
    (``P_HYST_DF``) to :math:`dF/d\Phi`. Returns ``(F, dF/dphi)`` like :func:`mmf`; the play
    states of this magnet, ``z[j, :]``, are updated in place (the kernel's hot path: no array
    view is created, and the function runs without the numba runtime, see ``NO_NRT``; inlined
    into its caller, which saves passing two arrays per magnet and sample).
    """
    f, df = mmf_anhysteretic(phi, gsum, p)
    if p[P_HYST] > 0.0:
        b = phi * p[P_INV_AP]
        n = int(p[P_NPLAY])
        lw = p[P_LFE] * p[P_HC] / n
        for k in range(n):
            r = p[P_PLAY_R0 + k]
            zk = min(max(z[j, k], b - r), b + r)     # branch-free play update
            z[j, k] = zk
            f += lw * (b - zk) * p[P_PLAY_INVR0 + k]
        df += p[P_HYST_DF]
    return f, df


@nb.njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def play_update(phi, z, p):
    """Advance the play-operator states ``z`` (in place) to the pole flux density of ``phi``."""
    if p[P_HYST] > 0.0:
        b = phi * p[P_INV_AP]
        n = int(p[P_NPLAY])
        for k in range(n):
            r = p[P_PLAY_R0 + k]
            if z[k] < b - r:
                z[k] = b - r
            elif z[k] > b + r:
                z[k] = b + r


@nb.njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def flux_from_current(i, gsum, z, p):
    r"""Static flux (Wb) for a DC current ``i``: solve :math:`N i = F_m(\Phi)` by Newton's method."""
    n = p[P_N]
    target = n * i
    phi = target * MU0 * p[P_AP] / (gsum + 1e-12)
    for _ in range(60):
        f, df = mmf(phi, gsum, z, p)
        step = (f - target) / df
        phi -= step
        if abs(step) <= 1e-13 * (abs(phi) + 1e-12):
            break
    return phi


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def force_from_flux(phi, p):
    r"""Attractive force (N) of one electromagnet along its axis, :math:`\Phi^2\cos\alpha/(\mu_0 A_p)`."""
    return phi * phi * p[P_COSA] / (MU0 * p[P_AP])


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def gap_sum(displacement, p):
    r"""Both airgaps of one magnet in series, :math:`2(g_0 - \xi\cos\alpha)` (m)."""
    return 2.0 * (p[P_G0] - displacement * p[P_COSA])


def static_force(params_packed: np.ndarray, current_a: float, displacement_m: float = 0.0) -> float:
    """Static force (N) of one magnet at DC current (hysteresis states at the demagnetised origin)."""
    z = np.zeros(MAX_PLAY)
    gs = gap_sum(displacement_m, params_packed)
    # With hysteresis the DC state depends on history: approach the current from zero so that the
    # play operators sit on the ascending branch, as after power-up.
    phi = 0.0
    n_steps = 50
    for k in range(1, n_steps + 1):
        phi = flux_from_current(current_a * k / n_steps, gs, z, params_packed)
        play_update(phi, z, params_packed)
    return float(force_from_flux(phi, params_packed))
