r"""Reluctance network of the 8-pole heteropolar stator: magnetic cross-coupling of the magnets.

The series model of :mod:`ssamb.sim.magnetics` gives every electromagnet its own flux loop (two
pole legs, two airgaps, one back-iron arc, one journal arc). In the real stator the eight poles
share the back-iron ring and the journal, so a magnet's flux also returns through the poles of
its neighbours whenever the magnetic potentials around the rings are not symmetric -- with a
displaced rotor (unequal gaps) and through the reluctance of the shared iron. This module solves
that network (linear iron, relative permeability :math:`\mu_r`) and hands the kernel the part
the series model lacks.

Network (paper section 2.2, reluctance network model [25])
-----------------------------------------------------------
Nodes: eight back-iron nodes :math:`b_p` at the pole roots and eight journal nodes :math:`r_p`
under the pole faces (poles at :math:`\theta_p`, counter-clockwise from the first ypos pole at
:math:`90^\circ - \alpha`). Branches:

* pole branch :math:`p` from :math:`b_p` to :math:`r_p`: the pole coil's MMF
  :math:`s_p N i_j / 2` (polarity :math:`s_p = \pm 1`, :math:`N/2` turns per pole coil), the pole
  leg :math:`(r_c - r_p)/(\mu_0\mu_r A_p)`, the airgap
  :math:`g_p/(\mu_0 A_p)` with :math:`g_p = g_0 - x\cos\theta_p - y\sin\theta_p`, and the radial
  journal leg :math:`\tfrac12 (r_j - r_r)/(\mu_0\mu_r A_r)`;
* back-iron arcs between adjacent :math:`b_p` (one pole pitch at :math:`(r_c + r_s)/2`, area
  :math:`A_b`), journal arcs between adjacent :math:`r_p` (one pitch at :math:`(r_r + r_j)/2`,
  area :math:`A_r`).

These are exactly the iron sections of the series model, so a magnet's own loop in the network
has the series model's reluctance. With the pole fluxes :math:`\Phi_p` (stator to rotor) the
flux per turn linked by magnet :math:`j` is :math:`\Phi_j = \tfrac12\sum_{p\in j} s_p\Phi_p`, and
the network is the linear map :math:`\Phi = P(x, y)\,N i` (a symmetric 4x4 permeance matrix).
Its inverse :math:`R_{net} = P^{-1}` gives the coil MMFs for given fluxes,
:math:`N i = R_{net}\Phi`.

What the kernel adds
--------------------
The kernel keeps the series model (with saturation, hysteresis and eddy currents on each
magnet's own flux) and adds the coupling

.. math:: N i = \mathcal F_{series}(\Phi) + Q(x, y)\,\Phi, \qquad
          Q = R_{net} - \operatorname{diag}(R_{series}),

:math:`R_{series,j} = (g_{p_1} + g_{p_2})/(\mu_0 A_p) + l_{eq}/(\mu_0\mu_r A_p)`, together with the
force it implies by virtual work at constant flux, :math:`F = -\tfrac12\Phi^T\,\partial Q/\partial
(x, y)\,\Phi`. :func:`coupling_tables` tabulates :math:`Q` and its gradient on a grid over the
backup-bearing clearance; the kernel interpolates them bilinearly.

With ideal iron (:math:`\mu_r\to\infty`) the network reduces to a floating journal potential
:math:`u`: :math:`\Phi_p = (s_p N i_j/2 - u)/\mathcal R_p`,
:math:`u = \sum_p (s_p N i_j/2)/\mathcal R_p \big/ \sum_p 1/\mathcal R_p`, which the tests solve
by hand.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from .params import MU0

__all__ = ["POLE_SEQUENCES", "pole_layout", "network_permeance", "coupling_matrix", "coupling_tables",
           "GRID_N"]

#: pole polarity sequences, counter-clockwise from the first ypos pole (90 deg - alpha)
POLE_SEQUENCES = ("NSNSNSNS", "NSSNNSSN")
#: magnet (ypos, yneg, xpos, xneg) of the poles in counter-clockwise order from 90 deg - alpha
_POLE_MAGNET = (0, 0, 3, 3, 1, 1, 2, 2)
#: grid points per axis of the coupling tables
GRID_N = 25


def pole_layout(alpha_rad: float, sequence: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pole angles (rad), owning magnet index and polarity (+1 N, -1 S) of the eight poles.

    Magnet axes: ypos 90 deg, xneg 180 deg, yneg 270 deg, xpos 0 deg; each magnet's poles sit at
    its axis -/+ alpha, listed counter-clockwise from 90 deg - alpha.
    """
    if sequence not in POLE_SEQUENCES:
        raise ValueError(f"pole sequence {sequence!r}: must be one of {', '.join(POLE_SEQUENCES)}")
    axes = (math.pi / 2, 3 * math.pi / 2, 0.0, math.pi)
    mag = np.array(_POLE_MAGNET)
    theta = np.array([axes[m] + (-alpha_rad if k % 2 == 0 else alpha_rad) for k, m in enumerate(mag)])
    pol = np.array([1.0 if c == "N" else -1.0 for c in sequence])
    return theta, mag, pol


def _branch_reluctances(geom: dict, x, y, theta: np.ndarray) -> np.ndarray:
    """Reluctance (A/Wb) of every pole branch (pole leg, airgap, radial journal leg); (B, 8)."""
    gaps = geom["g0"] - np.outer(x, np.cos(theta)) - np.outer(y, np.sin(theta))
    return geom["r_leg"] + gaps / (MU0 * geom["ap"])


def _permeance_batch(geom: dict, x, y) -> np.ndarray:
    """:func:`network_permeance` for arrays of rotor positions, shape (B, 4, 4)."""
    x = np.atleast_1d(np.asarray(x, float))
    y = np.atleast_1d(np.asarray(y, float))
    theta, mag, pol = pole_layout(geom["alpha"], geom["sequence"])
    yb = 1.0 / _branch_reluctances(geom, x, y, theta)                 # (B, 8)
    n = 8
    ring = np.zeros((2 * n, 2 * n))                                    # the two iron rings
    for p in range(n):
        q = (p + 1) % n
        for a, b, g in ((p, q, 1.0 / geom["r_back_arc"]), (n + p, n + q, 1.0 / geom["r_rot_arc"])):
            ring[[a, b], [a, b]] += g
            ring[a, b] -= g
            ring[b, a] -= g
    idx = np.arange(n)
    A = np.repeat(ring[None], len(x), axis=0)
    A[:, idx, idx] += yb
    A[:, n + idx, n + idx] += yb
    A[:, idx, n + idx] -= yb
    A[:, n + idx, idx] -= yb
    # pole MMFs per ampere-turn of each magnet (8 x 4); branch flux y_p (psi_b - psi_r + mmf_p):
    # injections y_p mmf_p at r_p and -y_p mmf_p at b_p; back-iron node 0 grounded
    mmf = np.where(mag[:, None] == np.arange(4)[None, :], 0.5 * pol[:, None], 0.0)
    rhs = np.concatenate([-yb[:, :, None] * mmf, yb[:, :, None] * mmf], axis=1)   # (B, 16, 4)
    psi = np.zeros_like(rhs)
    psi[:, 1:] = np.linalg.solve(A[:, 1:, 1:], rhs[:, 1:])
    phi_pole = yb[:, :, None] * (psi[:, :n] - psi[:, n:] + mmf)                 # (B, 8, 4)
    P = 0.5 * np.einsum("pk,bpj->bkj", np.where(mag[:, None] == np.arange(4), pol[:, None], 0.0), phi_pole)
    return 0.5 * (P + np.swapaxes(P, 1, 2))


def network_permeance(geom: dict, x: float, y: float) -> np.ndarray:
    r"""Coil permeance matrix :math:`P` (Wb per ampere-turn), :math:`\Phi = P\,N i` (4x4, symmetric).

    ``geom`` holds ``g0, ap, r_leg, r_back_arc, r_rot_arc, alpha, sequence`` (see
    :func:`geometry_of`). Solves the nodal equations of the 16-node network for a unit MMF of
    each magnet in turn (back-iron node 0 grounded).
    """
    return _permeance_batch(geom, x, y)[0]


def _coupling_batch(geom: dict, x, y) -> np.ndarray:
    x = np.atleast_1d(np.asarray(x, float))
    y = np.atleast_1d(np.asarray(y, float))
    theta, mag, _ = pole_layout(geom["alpha"], geom["sequence"])
    gaps = geom["g0"] - np.outer(x, np.cos(theta)) - np.outer(y, np.sin(theta))
    series = np.stack([gaps[:, mag == j].sum(axis=1) for j in range(4)], axis=1) / (MU0 * geom["ap"])
    series += geom["r_iron_loop"]
    q = np.linalg.inv(_permeance_batch(geom, x, y))
    q[:, np.arange(4), np.arange(4)] -= series
    return q


def coupling_matrix(geom: dict, x: float, y: float) -> np.ndarray:
    r""":math:`Q = P^{-1} - \operatorname{diag}(R_{series})` (A/Wb) at rotor position (x, y)."""
    return _coupling_batch(geom, x, y)[0]


def geometry_of(par) -> dict:
    """Network geometry from :class:`~ssamb.sim.params.AMBParams` (the series model's sections)."""
    mu = MU0 * par.mu_r
    ap = par.pole_area_m2
    half_leg = 0.5 * par.l_pole_m / (mu * ap)                    # one pole leg
    rot_radial = 0.5 * par.l_rotor_radial_m / (mu * par.a_rotor_m2)   # one radial journal leg
    return {
        "g0": par.airgap_m, "ap": ap, "alpha": par.pole_half_angle_rad, "sequence": par.pole_sequence,
        "r_leg": half_leg + rot_radial,
        "r_back_arc": par.l_back_m / (mu * par.a_back_m2),
        "r_rot_arc": par.l_rotor_arc_m / (mu * par.a_rotor_m2),
        "r_iron_loop": par.l_eq_m / (mu * ap),
    }


#: upper-triangle order of a symmetric 4x4 matrix in the tables (kernel: ``_sym``)
UPPER = tuple((j, k) for j in range(4) for k in range(j, 4))


#: geometries whose tables are kept: a close-the-loop fit steps the airgap and the permeability of
#: every model it replays, and returns to earlier ones (150 kB each)
@lru_cache(maxsize=128)
def _tables(key: tuple) -> np.ndarray:
    geom = dict(key[0])
    half = key[1]
    xs = np.linspace(-half, half, GRID_N)
    gx, gy = (a.ravel() for a in np.meshgrid(xs, xs, indexing="ij"))
    h = 1e-3 * half
    rows, cols = np.array(UPPER).T
    mats = (_coupling_batch(geom, gx, gy),
            (_coupling_batch(geom, gx + h, gy) - _coupling_batch(geom, gx - h, gy)) / (2 * h),
            (_coupling_batch(geom, gx, gy + h) - _coupling_batch(geom, gx, gy - h)) / (2 * h))
    tab = np.concatenate([m[:, rows, cols] for m in mats], axis=1).reshape(GRID_N, GRID_N, 30)
    tab.setflags(write=False)
    return tab


def coupling_tables(par) -> tuple[np.ndarray, float]:
    r"""Tables of :math:`Q`, :math:`\partial Q/\partial x`, :math:`\partial Q/\partial y` on a
    ``GRID_N`` x ``GRID_N`` grid over :math:`\pm 1.25` times the backup clearance.

    Returns ``(tables, half_width_m)`` with ``tables`` of shape (GRID_N, GRID_N, 30): at every
    grid point (x, y) the upper triangles (order :data:`UPPER`) of the three symmetric matrices.
    Cached per geometry.
    """
    geom = geometry_of(par)
    half = 1.25 * par.clearance_m
    return _tables((tuple(sorted(geom.items())), half)), half
