"""Generalized plant with additive uncertainty (Figs. 5-6) against a hand-derived loop."""
import control
import numpy as np
import pytest

from ssamb.mu import mussv
from ssamb.generalized_plant import case_structure, n11_function, uncertainty_loop

DT = 1 / 83300.0
CUR = ["i_ypos", "i_yneg", "i_xpos", "i_xneg"]


def _static(D, ins, outs, name):
    D = np.atleast_2d(np.asarray(D, float))
    return control.ss(np.zeros((0, 0)), np.zeros((0, len(ins))), np.zeros((len(outs), 0)), D, DT,
                      inputs=ins, outputs=outs, name=name)


def _loop(g=2.0, s=1e-5, b=3e-6, kx=1e3, ky=4e3):
    # self-sensing with one sample of delay: y_ss(k) = s * i_ypos(k-1)
    ss = control.ss([[0.0]], [[1.0]], [[s]], [[0.0]], DT, inputs=["i_ypos"], outputs=["y_ss"], name="ss")
    amp = _static([[0, g, 0, 0], [0, -g, 0, 0], [g, 0, 0, 0], [-g, 0, 0, 0]],
                  ["u_x_cmd", "u_y_cmd", "x_meas", "y_meas"], CUR, "amp")
    # plant: one sample of delay, x = b (i_xpos - i_xneg), y = b (i_ypos - i_yneg)
    plant = control.ss(np.zeros((2, 2)), b * np.array([[0, 0, 1, -1], [1, -1, 0, 0]]), np.eye(2),
                       np.zeros((2, 4)), DT, inputs=CUR, outputs=["x_meas", "y_meas"], name="plant")
    return uncertainty_loop(plant, amp, ss, _static([[kx]], ["u"], ["y"], "px"), _static([[ky]], ["u"], ["y"], "py"))


def test_selfsensing_transfer_matches_hand_derivation():
    g, s, ky = 2.0, 1e-5, 4e3
    loop = _loop(g=g, s=s, ky=ky)
    w = control.tf([1.0], [1.0])   # unit weight
    f = n11_function(loop, {"selfsensing": w}, "selfsensing")
    for hz in (3.0, 300.0, 8000.0):
        z = np.exp(2j * np.pi * hz * DT)
        expected = -g * ky / (1 + g * ky * s / z)       # T(d_y_ss -> i_ypos)
        assert f(hz)[0, 0] == pytest.approx(expected, rel=1e-9)


def test_weight_scales_n11_and_mu():
    loop = _loop()
    s = control.tf("s")
    w = 1e-6 * (1 + s / 100) / (1 + s / 1e4) ** 2
    f1 = n11_function(loop, {"selfsensing": w}, "selfsensing")
    f2 = n11_function(loop, {"selfsensing": w}, "selfsensing", scale=3.0)
    m = f1(20.0)
    assert f2(20.0)[0, 0] == pytest.approx(3 * m[0, 0])
    res = mussv(m, case_structure("selfsensing"))
    assert res.upper == pytest.approx(abs(m[0, 0]), rel=1e-6)


def test_block_structures_and_shapes():
    assert case_structure("selfsensing") == [[1, 1]]
    assert case_structure("amplifier") == [[4, 2]]
    assert case_structure("plant") == [[2, 4]]
    assert case_structure("all") == [[1, 1], [4, 2], [2, 4]]
    loop = _loop()
    one = control.tf([1.0], [1.0])
    m = n11_function(loop, {"selfsensing": one, "amplifier": one, "plant": one}, "all")(10.0)
    assert m.shape == (7, 7)   # (sum c) x (sum r)
    with pytest.raises(ValueError, match="weight"):
        n11_function(loop, {"selfsensing": one}, "all")
    with pytest.raises(ValueError, match="case"):
        case_structure("rotor")
