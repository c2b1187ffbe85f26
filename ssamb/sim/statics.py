r"""Static magnetics and the initial state: coupled DC fluxes, forces, the levitated equilibrium.

With the stator network on (``magnetics.cross_coupling``) the four magnets' DC fluxes solve
:math:`N i = \mathcal F_m(\Phi) + Q(x, y)\Phi` jointly (Newton's method on the 4x4 system), and
the force adds :math:`-\tfrac12\Phi^T\partial Q/\partial(x, y)\Phi` to the series magnets' pull
(:mod:`ssamb.sim.network`); the kernel uses the same interpolated tables, so a run started
from :func:`equilibrium` starts at rest.
"""
from __future__ import annotations

import numba as nb
import numpy as np
from scipy.optimize import brentq

from ..config import ConfigError
from .dsp import selfsensing_state
from .kernel import (S_DUTY, S_INTEG, S_IREF, S_IREFN, S_M, S_PHASE, S_PHI, S_PIDX_I, S_PIDY_I, S_VOLT,
                     S_X, S_XS, S_Y, _interp_q, new_state)
from .magnetics import MAX_PLAY, flux_from_current, gap_sum, mmf
from .network import UPPER, coupling_tables
from .params import MU0, P_AP, P_COSA, P_HYST, P_N, P_XNET, AMBParams

__all__ = ["network_tables", "static_fluxes", "static_forces", "equilibrium", "linear_stiffness", "initial_state"]


def network_tables(par: AMBParams) -> np.ndarray:
    """Coupling tables for the kernel (a 1x1 dummy grid when the network is off)."""
    if not par.cross_coupling:
        return np.zeros((2, 2, 30))
    return np.ascontiguousarray(coupling_tables(par)[0])


#: upper-triangle index of every entry of a symmetric 4x4 matrix
_FULL = np.array([[UPPER.index((min(j, k), max(j, k))) for k in range(4)] for j in range(4)])


def _coupling(packed, qtab, x, y) -> np.ndarray:
    """Q, dQ/dx, dQ/dy (3 x 4 x 4) interpolated as in the kernel (zero with the network off)."""
    qm = np.zeros(30)
    if packed[P_XNET] > 0.5:
        _interp_q(qtab, packed, x, y, qm)
    return qm.reshape(3, 10)[:, _FULL]


@nb.njit(cache=True)
def _coupled_fluxes(p, q, cur, gs):
    r"""Newton's method on :math:`N i = \mathcal F_m(\Phi) + Q\Phi` (hysteresis off in ``p``)."""
    z = np.zeros(MAX_PLAY)
    n = p[P_N]
    phi = np.empty(4)
    for j in range(4):
        phi[j] = flux_from_current(cur[j], gs[j], z, p)
    if not np.any(q != 0.0):
        return phi
    for _ in range(50):
        jac = q.copy()
        r = q @ phi - n * cur
        for j in range(4):
            f, df = mmf(phi[j], gs[j], z, p)
            r[j] += f
            jac[j, j] += df
        step = np.linalg.solve(jac, r)
        phi -= step
        if np.max(np.abs(step)) <= 1e-14 * (np.max(np.abs(phi)) + 1e-12):
            break
    return phi


class _StaticCircuit:
    """The static magnetic circuit at one rotor position ``(x_m, y_m)``: the hysteresis-free
    parameters, the gap sums and the interpolated network coupling, evaluated once for the many
    currents of a root search (:func:`equilibrium`)."""

    def __init__(self, packed: np.ndarray, qtab: np.ndarray, x_m: float = 0.0, y_m: float = 0.0):
        self.packed = packed
        self.p = packed.copy()
        self.p[P_HYST] = 0.0
        self.gs = np.array([gap_sum(d, self.p) for d in (y_m, -y_m, x_m, -x_m)])
        self.qm = _coupling(packed, qtab, x_m, y_m)
        self.q = np.ascontiguousarray(self.qm[0])
        # force_from_flux's factors, applied to the four fluxes at once (the same operations)
        self.cos_alpha = packed[P_COSA]
        self.mu0_ap_h_m = MU0 * packed[P_AP]

    def fluxes(self, currents_a) -> np.ndarray:
        """:func:`static_fluxes` at this position."""
        cur = np.maximum(np.asarray(currents_a, float), 0.0)
        return _coupled_fluxes(self.p, self.q, cur, self.gs)

    def forces(self, phi) -> tuple[float, float]:
        """:func:`static_forces` at this position."""
        phi = np.asarray(phi, float)
        f = phi * phi * self.cos_alpha / self.mu0_ap_h_m       # force_from_flux of each magnet
        fx = f[2] - f[3] - 0.5 * phi @ self.qm[1] @ phi
        fy = f[0] - f[1] - 0.5 * phi @ self.qm[2] @ phi
        return float(fx), float(fy)


def static_fluxes(packed: np.ndarray, qtab: np.ndarray, currents_a, x_m: float = 0.0,
                  y_m: float = 0.0) -> np.ndarray:
    r"""DC fluxes per turn (Wb) of the four magnets for coil currents ``currents_a`` (hysteresis
    off): :math:`N i = \mathcal F_m(\Phi) + Q\Phi`, Newton's method from the uncoupled fluxes."""
    return _StaticCircuit(packed, qtab, x_m, y_m).fluxes(currents_a)


def static_forces(packed: np.ndarray, qtab: np.ndarray, phi, x_m: float = 0.0, y_m: float = 0.0):
    """Magnetic force (Fx, Fy) in N for the fluxes ``phi`` (series pull plus network coupling)."""
    return _StaticCircuit(packed, qtab, x_m, y_m).forces(phi)


def equilibrium(par: AMBParams, packed: np.ndarray, qtab: np.ndarray | None = None, f_x_n: float = 0.0,
                f_y_n: float = 0.0, x_m: float = 0.0, y_m: float = 0.0) -> dict:
    """Static equilibrium of the levitated rotor at ``(x_m, y_m)`` under an external force.

    Solves for the differential control currents :math:`u_x, u_y` such that the magnetic force
    balances this bearing's share of the weight and the external force,
    :math:`F_y(i_0+u_y, i_0-u_y, u_x) = w m g - f_y`, :math:`F_x = -f_x`, with the static
    (hysteresis-free) magnetic circuit; with the network on, the axes are coupled and solved in
    turn until both balance. Returns currents, fluxes, the control currents and the steady duty
    cycles.
    """
    qtab = network_tables(par) if qtab is None else qtab
    i0 = par.i_bias_a
    ty = par.weight_n - f_y_n
    tx = -f_x_n
    lim = min(par.u_max_a, i0) * 0.999
    circuit = _StaticCircuit(packed, qtab, x_m, y_m)

    def forces(ux, uy):
        return circuit.forces(circuit.fluxes(np.array([i0 + uy, i0 - uy, i0 + ux, i0 - ux])))

    ux = uy = 0.0
    try:
        for _ in range(20):
            uy_new = brentq(lambda u: forces(ux, u)[1] - ty, -lim, lim, xtol=1e-12)
            ux_new = brentq(lambda u: forces(u, uy_new)[0] - tx, -lim, lim, xtol=1e-12)
            done = abs(uy_new - uy) < 1e-11 and abs(ux_new - ux) < 1e-11
            ux, uy = ux_new, uy_new
            if done:
                break
    except ValueError:
        raise ConfigError(
            f"no levitated equilibrium: the control current would exceed controller.u_max_a = {par.u_max_a} A "
            f"(load {tx:.3g} N in x, {ty:.3g} N in y: the weight from table1.mass_kg, gravity_m_per_s2 and "
            "weight_share plus the effects' forces at t = 0; the magnets' pull from table1.i_bias_a, "
            "table1.airgap_m, table1.coil_turns, geometry.coils_per_magnet and table1.mu_r)") from None
    cur = np.array([i0 + uy, i0 - uy, i0 + ux, i0 - ux])
    phis = circuit.fluxes(cur)
    duty = 0.5 + par.r_coil_ohm * cur / (2 * par.v_supply_v)
    return {"u_x": ux, "u_y": uy, "currents_a": cur, "phi_wb": phis, "duty": duty, "x_m": x_m, "y_m": y_m}


def linear_stiffness(par: AMBParams, axis: str = "y", packed: np.ndarray | None = None,
                     qtab: np.ndarray | None = None) -> tuple[float, float]:
    r"""Current and position stiffness :math:`(k_i, k_s)` of the whole static model (series
    magnets and, when on, the stator network) at the levitated equilibrium, along ``axis``:
    central differences of the force in the differential control current and in the rotor
    position at the equilibrium currents (hysteresis off).

    With the network on, :math:`k_s` exceeds the series model's :meth:`AMBParams.ki_ks`: every pole
    of the other axis' magnets returns its flux through the common journal, so its flux follows
    its own gap and the magnets pull sideways on a displaced rotor (the series model forces a
    magnet's two poles to carry one flux).
    """
    packed = par.pack() if packed is None else packed
    qtab = network_tables(par) if qtab is None else qtab
    eq = equilibrium(par, packed, qtab)
    cur = np.asarray(eq["currents_a"], float)
    ax = 1 if axis == "y" else 0
    sign = np.array([1.0, -1.0, 0.0, 0.0]) if axis == "y" else np.array([0.0, 0.0, 1.0, -1.0])
    di, dx = 1e-3, 1e-7

    def force(c, x, y):
        circuit = _StaticCircuit(packed, qtab, x, y)
        return circuit.forces(circuit.fluxes(c))[ax]

    ki = (force(cur + di * sign, 0.0, 0.0) - force(cur - di * sign, 0.0, 0.0)) / (2 * di)
    d = (dx, 0.0) if axis == "x" else (0.0, dx)
    ks = (force(cur, *d) - force(cur, -d[0], -d[1])) / (2 * dx)
    return float(ki), float(ks)


def initial_state(par: AMBParams, start: str, eq: dict | None):
    """Kernel state at t = 0: levitated at the equilibrium ``eq``, or resting on the backup bearing.

    Returns ``(st, ss, z, lad, rings, ss_rings)`` (see :func:`ssamb.sim.kernel.run_chunk`).
    """
    st, z, lad, rings = new_state()
    for j in range(4):
        st[S_M + j] = -1.0     # first PWM period starts at t = 0
        st[S_PHASE + j] = 2.0
        st[S_VOLT + j] = -1.0
    if start == "levitated":
        st[S_X], st[S_Y] = eq["x_m"], eq["y_m"]
        st[S_XS] = st[S_X]
        for j in range(4):
            st[S_PHI + j] = eq["phi_wb"][j]
            lad[j, :] = eq["phi_wb"][j]
            st[S_INTEG + j] = eq["duty"][j] - 0.5
            st[S_DUTY + j] = eq["duty"][j]
            st[S_IREF + j] = st[S_IREFN + j] = eq["currents_a"][j]
            z[j, :] = eq["phi_wb"][j] / par.pole_area_m2
        st[S_PIDX_I] = eq["u_x"]
        st[S_PIDY_I] = eq["u_y"]
        rings[0, :] = st[S_X]
        rings[1, :] = st[S_Y]
    elif start == "rest":
        st[S_Y] = -(par.clearance_m + par.weight_n / par.contact_stiffness_n_per_m)
        for j in range(4):
            st[S_DUTY + j] = 0.5
            st[S_IREFN + j] = par.i_bias_a
    else:
        raise ConfigError(f"experiment start '{start}': must be 'rest' or 'levitated'")
    ss, ss_rings = selfsensing_state(st[S_Y] if start == "levitated" else 0.0)
    return st, ss, z, lad, rings, ss_rings
