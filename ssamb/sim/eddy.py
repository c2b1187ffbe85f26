r"""Eddy currents in the laminated iron: exact lamination impedance and its fitted ladder network.

A lamination of thickness :math:`d`, conductivity :math:`\sigma` and permeability
:math:`\mu = \mu_0\mu_r` carries the flux of a magnetic field that diffuses in from both faces
(1-D diffusion across the thickness). Seen from the magnetic circuit, a section of length
:math:`l` and area :math:`A` has the complex reluctance (classical lamination solution)

.. math:: \mathcal R(s) = \frac{l}{\mu A}\, z(s), \qquad
          z(s) = \sqrt{s\tau}\,\coth\sqrt{s\tau}, \qquad \tau = \frac{\mu\sigma d^2}{4},

which is :math:`1 + s\tau/3` at low frequency (the classical eddy conductance
:math:`g_e = l\sigma d^2/(12 A)` of a shorted turn) and grows like :math:`\sqrt{s}` once the
skin depth :math:`\delta = \sqrt{2/(\omega\mu\sigma)}` is below the half-thickness (above about
:math:`1/(2\pi\tau)` = 0.5 kHz for 0.35 mm SiFe with :math:`\mu_r` = 4000; at 30 kHz
:math:`\delta` = 32 um against 175 um). Every iron section shares :math:`\tau`, so the whole
iron path is :math:`\mathcal R_{fe}\,z(s)` with :math:`\mathcal R_{fe} = \sum_s l_s/(\mu A_s)`.

Ladder network (the kernel's model)
-----------------------------------
The excess reluctance :math:`z(s) - 1 = \sum_{k\ge1} 2 s\tau/(s\tau + k^2\pi^2)` is a sum of
first-order sections. The kernel uses ``K`` of them with fitted weights,

.. math:: z_K(s) = 1 + \sum_{k=1}^{K} a_k \frac{s\tau_k}{1 + s\tau_k}, \qquad
          \tau_k = \tau_1 / 8^{k-1},

fitted (:func:`fit_ladder`, least squares on :math:`\log z_K - \log z`, magnitude and phase) to
the exact :math:`z` from DC to ``f_max_hz`` (200 kHz by default). The time constants are spaced
by a factor 8 so that the kernel needs one exponential per integration segment
(:math:`e^{-h/\tau_{k+1}} = (e^{-h/\tau_k})^8`). In the time domain each section is a lagged
copy :math:`\Psi_k` of the flux,

.. math:: \mathcal F_{eddy} = \mathcal R_{fe}\sum_k a_k (\Phi - \Psi_k), \qquad
          \tau_k\dot\Psi_k = \Phi - \Psi_k,

an MMF the coil must supply on top of the static one: an edge of the coil voltage makes the
current rise like :math:`\sqrt t` over the section time constants instead of the
instantaneous step of a single shorted turn. Three sections reproduce :math:`z` within 0.5 dB and
3 degrees to 200 kHz (test ``test_eddy_ladder_matches_lamination_impedance``).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy.optimize import least_squares

__all__ = ["LADDER_RATIO", "MAX_LADDER", "lamination_tau", "lamination_z", "ladder_z", "fit_ladder"]

#: ratio of successive ladder time constants (a power of two: the kernel squares, never exponentiates)
LADDER_RATIO = 8
#: most ladder sections the kernel supports
MAX_LADDER = 6


def lamination_tau(mu_r: float, sigma_s_per_m: float, thickness_m: float) -> float:
    r"""Diffusion time constant :math:`\tau = \mu_0\mu_r\sigma d^2/4` (s)."""
    return 4e-7 * math.pi * mu_r * sigma_s_per_m * thickness_m**2 / 4.0


def lamination_z(f_hz, tau_s: float) -> np.ndarray:
    r"""Exact normalised reluctance :math:`z = \sqrt{s\tau}\coth\sqrt{s\tau}` at :math:`s = j2\pi f`."""
    s = 2j * math.pi * np.asarray(f_hz, float)
    x = np.sqrt(s * tau_s)
    out = np.ones_like(x)
    small = np.abs(x) < 1e-4
    out[small] = 1.0 + x[small] ** 2 / 3.0
    big = ~small
    out[big] = x[big] / np.tanh(x[big])
    return out


def ladder_z(f_hz, weights, taus) -> np.ndarray:
    r"""Normalised reluctance of the ladder, :math:`1 + \sum_k a_k s\tau_k/(1 + s\tau_k)`."""
    s = 2j * math.pi * np.asarray(f_hz, float)[None, :]
    a = np.asarray(weights, float)[:, None]
    t = np.asarray(taus, float)[:, None]
    return 1.0 + np.sum(a * s * t / (1.0 + s * t), axis=0)


#: kept for every lamination time constant a close-the-loop fit replays (a few hundred bytes each)
@lru_cache(maxsize=512)
def fit_ladder(tau_s: float, order: int, f_max_hz: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Weights :math:`a_k` and time constants :math:`\\tau_k` of the ``order``-section ladder.

    Least squares on the complex log-ratio over DC and 400 log-spaced frequencies from 1 Hz to
    ``f_max_hz``, started from the first terms of the exact partial-fraction expansion
    (:math:`a_k = 2`, :math:`\\tau_1 = \\tau/\\pi^2`). Deterministic (no random start).
    """
    if not 1 <= order <= MAX_LADDER:
        raise ValueError(f"ladder order {order}: must be 1..{MAX_LADDER}")
    f = np.concatenate([[0.0], np.logspace(0.0, math.log10(f_max_hz), 400)])
    z = lamination_z(f, tau_s)
    ratios = float(LADDER_RATIO) ** np.arange(order)

    def resid(p):
        r = np.log(ladder_z(f, np.exp(p[:order]), math.exp(p[order]) / ratios) / z)
        return np.concatenate([r.real, r.imag])

    p0 = np.concatenate([np.full(order, math.log(2.0)), [math.log(tau_s / math.pi**2)]])
    sol = least_squares(resid, p0, xtol=1e-12, ftol=1e-12)
    weights = tuple(float(v) for v in np.exp(sol.x[:order]))
    taus = tuple(float(v) for v in math.exp(sol.x[order]) / ratios)
    return weights, taus
