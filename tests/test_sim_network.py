"""Cross-coupling of the heteropolar stator: the reluctance network against hand solutions."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ssamb.config import apply_overrides, load_config
from ssamb.sim import amb_params
from ssamb.sim.network import coupling_matrix, geometry_of, network_permeance, pole_layout
from ssamb.sim.params import MU0
from ssamb.sim.statics import network_tables, static_fluxes, static_forces


@pytest.fixture(scope="module")
def par():
    cfg = apply_overrides(load_config(), {"magnetics.saturation": False, "magnetics.hysteresis": False})
    return amb_params(cfg)


def _hand_permeance(par, x, y):
    """Ideal iron, solved by hand: back iron at potential 0, journal at u; pole p carries
    Phi_p = (s_p N i/2 - u)/R_p with R_p = g_p/(mu0 A_p); flux conservation on the journal gives
    u = (N/2) sum_k a_k i_k / S, a_k = sum_{p in k} s_p/R_p, S = sum_p 1/R_p, hence
    Phi_j = (N/4) [ (sum_{p in j} 1/R_p) i_j - a_j sum_k a_k i_k / S ]."""
    theta, mag, pol = pole_layout(par.pole_half_angle_rad, par.pole_sequence)
    inv_r = MU0 * par.pole_area_m2 / (par.airgap_m - x * np.cos(theta) - y * np.sin(theta))
    a = np.array([np.sum((pol * inv_r)[mag == j]) for j in range(4)])
    own = np.array([np.sum(inv_r[mag == j]) for j in range(4)])
    return 0.25 * (np.diag(own) - np.outer(a, a) / np.sum(inv_r))


@pytest.mark.parametrize("x, y", [(1.0e-4, 0.0), (1.0e-4, 1.0e-4), (-0.5e-4, 1.5e-4)])
def test_network_ideal_iron_matches_hand_solution(par, x, y):
    """With mu_r -> infinity the 16-node network is the hand-solved floating-journal circuit."""
    geom = geometry_of(par)
    scale = 1e-7                    # iron reluctances x 1e-7: mu_r = 4e10
    for k in ("r_leg", "r_back_arc", "r_rot_arc", "r_iron_loop"):
        geom[k] *= scale
    p_net = network_permeance(geom, x, y)
    p_hand = _hand_permeance(par, x, y)
    assert np.allclose(p_net, p_hand, rtol=1e-5, atol=1e-6 * np.max(np.abs(p_hand)))


def test_coupling_sign_and_size_for_displaced_rotor(par):
    """Sign and size of the coupling the displaced rotor brings, against the hand solution.

    Ideal iron, rotor at (100, 100) um, poles NSNSNSNS: the rotor approaches the ypos N pole at
    67.5 deg and the xpos S pole at 22.5 deg, so a_ypos > 0 > a_xpos and the journal potential
    couples them by -a_ypos a_xpos / (4 S) > 0: ypos flux returns through the near xpos pole in
    the direction of xpos's own flux. It is a few per mille of the self permeance. With the
    config's iron (mu_r = 4000) the displacement-induced part (the difference to the centred
    rotor) keeps the sign and grows to 1.8 times the ideal-iron value: the potentials along the
    back-iron and journal rings shift with the unequal gaps too, at first order in the
    displacement, where the floating journal alone acts at second order."""
    assert par.pole_sequence == "NSNSNSNS"
    x = y = 1.0e-4
    hand = _hand_permeance(par, x, y)
    assert hand[0, 0] > 0 and hand[0, 2] > 0                      # sign
    assert 1e-3 < hand[0, 2] / hand[0, 0] < 1e-2                    # size: a few per mille
    geom = geometry_of(par)
    p_net = network_permeance(geom, x, y) - network_permeance(geom, 0.0, 0.0)
    ideal = hand[0, 2] - _hand_permeance(par, 0, 0)[0, 2]
    assert 1.0 < p_net[0, 2] / ideal < 3.0


def test_coupling_symmetries(par):
    """Q is symmetric, vanishes in the series limit's own loops only through the iron, and the
    x- and y-displacements act alike on the magnets of their axis (stator symmetry)."""
    geom = geometry_of(par)
    q0 = coupling_matrix(geom, 0.0, 0.0)
    assert np.allclose(q0, q0.T, atol=1e-9 * np.abs(q0).max())
    r_gap = 2 * par.airgap_m / (MU0 * par.pole_area_m2)
    assert 1e-4 < np.abs(q0).max() / r_gap < 1e-2                  # iron coupling: per mille of the gap
    qx = coupling_matrix(geom, 1e-4, 0.0)
    qy = coupling_matrix(geom, 0.0, 1e-4)
    # a y displacement does to (ypos, yneg) what an x displacement does to (xpos, xneg)
    assert qy[0, 0] == pytest.approx(qx[2, 2], rel=1e-9)
    assert qy[0, 1] == pytest.approx(qx[2, 3], rel=1e-9)


def test_static_force_equals_network_maxwell_force(par):
    """Series magnets + coupling Q (forces by virtual work through the interpolated tables)
    against the Maxwell force of the network's own pole fluxes, for a displaced rotor and unequal
    currents (linear iron)."""
    x, y = 0.8e-4, -1.2e-4
    currents = np.array([3.4, 2.6, 3.2, 2.9])
    packed = par.pack()
    qtab = network_tables(par)
    phi = static_fluxes(packed, qtab, currents, x, y)
    fx, fy = static_forces(packed, qtab, phi, x, y)
    # the network's own solution: pole fluxes for these currents, Maxwell stress on each pole face
    geom = geometry_of(par)
    theta, mag, pol = pole_layout(par.pole_half_angle_rad, par.pole_sequence)
    phi_net = network_permeance(geom, x, y) @ (par.turns * currents)
    assert np.allclose(phi, phi_net, rtol=2e-4)
    h = 1e-9
    energy = []
    for dx, dy in ((h, 0), (-h, 0), (0, h), (0, -h)):
        r_net = np.linalg.inv(network_permeance(geom, x + dx, y + dy))
        energy.append(0.5 * phi_net @ r_net @ phi_net)
    f_ref = (-(energy[0] - energy[1]) / (2 * h), -(energy[2] - energy[3]) / (2 * h))
    assert fx == pytest.approx(f_ref[0], rel=2e-3)
    assert fy == pytest.approx(f_ref[1], rel=2e-3)
    assert math.isfinite(fx) and abs(fy) > 10.0


def test_network_position_stiffness_by_hand():
    """Why the network stiffens the plant: with a common journal (ideal iron, equal currents) each
    pole's flux follows its own gap, Phi_p = (N i/2) mu0 A / g_p, so the co-energy
    sum_p F^2 mu0 A/(2 g_p) gives k_s = N^2 i^2 mu0 A sum_p sin^2(theta_p)/(4 g0^3)
    = N^2 i^2 mu0 A / g0^3 (sum of sin^2 over the 8 poles = 4); the series model, whose two poles
    of a magnet carry one flux, gives k_s = N^2 i^2 mu0 A cos^2(alpha)/g0^3. Ratio 1/cos^2(alpha)
    = 1.17. Without the network the static model is the series one (AMBParams.ki_ks)."""
    from ssamb.sim.statics import linear_stiffness

    base = {"magnetics.saturation": False, "magnetics.hysteresis": False, "weight_share": 0.0,
            "table1.mu_r": 1.0e9}
    series = amb_params(apply_overrides(load_config(), {**base, "magnetics.cross_coupling": False}))
    network = amb_params(apply_overrides(load_config(), base))
    ki_s, ks_s = linear_stiffness(series)
    assert (ki_s, ks_s) == pytest.approx(series.ki_ks(0.0), rel=1e-4)
    _, ks_n = linear_stiffness(network)
    assert ks_n / ks_s == pytest.approx(1.0 / math.cos(network.pole_half_angle_rad) ** 2, rel=0.01)
