"""Tests of ssamb.identification.joint (selection by the assembled loop) and ssamb.peak_cause."""
from __future__ import annotations

import control
import numpy as np
import pytest

from ssamb.closed_loop import (assemble_closed_loop, lti_initial_state, simulate_closed_loop, stability,
                               to_continuous)
from ssamb.identification import IdentifiedModel, nrmse_fit
from ssamb.identification.joint import (Candidate, candidate_settings, identify_candidates, score_loop,
                                        select_loop)
from test_closed_loop import DT, FS, _known_linear_amb, _pulse_train


@pytest.fixture(scope="module")
def pid():
    from ssamb.config import load_config
    from ssamb.sim.controller import pid_discrete

    return pid_discrete(load_config())


def _as_model(sys, name: str) -> IdentifiedModel:
    """A known affine StateSpace (last input ``one``) as an IdentifiedModel."""
    ins = [c for c in sys.input_labels if c != "one"]
    return IdentifiedModel(np.asarray(sys.A), np.asarray(sys.B), np.asarray(sys.C), np.asarray(sys.D), DT, name,
                           tuple(ins), tuple(sys.output_labels), True, np.zeros(len(ins)),
                           np.zeros(sys.noutputs))


def _scaled(sys, k: float):
    """The system with its input matrix (hence its gain, affine column included) times k."""
    return control.ss(sys.A, np.asarray(sys.B) * k, sys.C, sys.D, sys.dt, inputs=sys.input_labels,
                      outputs=sys.output_labels)


def _cand(sub, label, sys, **kw):
    return Candidate(sub, {"method": label, "ss_f": 10, "ss_p": 10, "A_stability": False, "refine": "auto"},
                     None if sys is None else _as_model(sys, label), **kw)


@pytest.fixture(scope="module")
def known(pid):
    """Candidates around the known linear loop and a validation record from a loop that differs
    from every candidate (self-sensing gain 1.1, amplifier 5 % slower)."""
    P, G, S = _known_linear_amb()
    Gc = to_continuous(G, "zoh")
    G_slow = control.c2d(control.ss(Gc.A * 0.95, Gc.B * 0.95, Gc.C, Gc.D), DT, "zoh")
    G_slow = control.ss(G_slow.A, G_slow.B, G_slow.C, G_slow.D, DT, inputs=G.input_labels, outputs=G.output_labels)
    real = assemble_closed_loop(P, G_slow, _scaled(S, 1.1), pid, pid, require_stable=True)
    n = int(0.05 * FS)
    # like a simulator record: from the operating point without injection
    val = simulate_closed_loop(real, np.arange(n) * DT, 0.0, 0.0, _pulse_train(n, 0.2, 5), _pulse_train(n, 0.2, 6),
                               x0=lti_initial_state(real))
    cands = {"plant": [_cand("plant", "P", P)],
             "amplifier": [_cand("amplifier", "G", G), _cand("amplifier", "G_pos3", _pos_scaled(G, 3.0))],
             "selfsensing": [_cand("selfsensing", "S", S), _cand("selfsensing", "S_x10", _scaled(S, 10.0)),
                             _cand("selfsensing", "S_neg", _scaled(S, -1.0)),
                             _cand("selfsensing", "S_fail", None, error="RuntimeError: boom"),
                             _cand("selfsensing", "S_dup", S, same_as="S f10 p10")]}
    return cands, val


def _pos_scaled(G, k):
    B = np.asarray(G.B).copy()
    B[:, 2:4] *= k  # the position inputs x_meas, y_meas
    return control.ss(G.A, B, G.C, G.D, G.dt, inputs=G.input_labels, outputs=G.output_labels)


def test_candidate_settings_product_drops_a_stability_for_parsim():
    s = candidate_settings({"methods": ["N4SID", "PARSIM-K"], "horizons": [10, 20], "a_stability": [False, True]})
    assert len(s) == 2 * 2 * 2 - 2
    assert not any(x["A_stability"] for x in s if x["method"] == "PARSIM-K")
    assert all(x["ss_f"] == x["ss_p"] and x["refine"] == "auto" for x in s)


def test_select_loop_assembles_every_combination_and_keeps_the_stable_best(known, pid):
    cands, val = known
    sel = select_loop(cands, pid, pid, val)
    assert len(sel.table) == 1 * 2 * 3  # failed and duplicated candidates are not assembled
    for row in sel.table:  # the table's verdict is that of the one builder
        mods = {c.label: c.model for v in cands.values() for c in v if c.model is not None}
        cl = assemble_closed_loop(mods[row["plant"]], mods[row["amplifier"]], mods[row["selfsensing"]], pid, pid) \
            if row["stable"] else None
        assert row["stable"] == (row["spectral_radius"] < 1.0)
        assert ("fit_pct" in row) == row["stable"]
        if cl is not None:
            assert stability(cl).spectral_radius == pytest.approx(row["spectral_radius"], abs=1e-12)
    unstable = {r["selfsensing"] for r in sel.table if not r["stable"]}
    assert unstable == {"S_x10 f10 p10", "S_neg f10 p10"}
    assert {k: c.label for k, c in sel.choice.items()} == {"plant": "P f10 p10", "amplifier": "G f10 p10",
                                                             "selfsensing": "S f10 p10"}
    best = sel.best
    assert best["mean_fit_pct"] == max(r["mean_fit_pct"] for r in sel.table if r["stable"])
    assert 80.0 < best["fit_pct"]["y_meas"] < 99.9  # the record is not one the candidates made
    assert best["fit_pct"]["x_meas"] > 80.0
    assert len(sel.as_dict()["candidates"]["selfsensing"]) == 5


def test_select_loop_without_a_stable_combination_says_so(known, pid):
    cands, val = known
    only_bad = {**cands, "selfsensing": cands["selfsensing"][1:3]}
    sel = select_loop(only_bad, pid, pid, val)
    assert sel.choice is None and sel.best is None
    assert len(sel.table) == 4 and not any(r["stable"] for r in sel.table)
    assert min(r["spectral_radius"] for r in sel.table) > 1.0


def test_score_loop_fit_matches_a_direct_replay(known, pid):
    cands, val = known
    P, G, S = (cands[k][0].model for k in ("plant", "amplifier", "selfsensing"))
    sc = score_loop(P, G, S, pid, pid, val)
    cl = assemble_closed_loop(P, G, S, pid, pid)
    out = simulate_closed_loop(cl, val["t"], val["r_x"], val["r_y"], val["inj_x"], val["inj_y"],
                               x0=lti_initial_state(cl))
    assert sc["fit_pct"]["y_meas"] == pytest.approx(nrmse_fit(val["y_meas"], out["y_meas"]), abs=1e-6)


def test_identify_candidates_records_failures_and_duplicates():
    rng = np.random.default_rng(0)
    u = _pulse_train(4000, 1.0, 1)[:, None]
    a, b = 0.95, 0.1  # y+ = a y + b u (stable: A_stability changes nothing)
    y = np.zeros((4000, 1))
    for k in range(1, 4000):
        y[k] = a * y[k - 1] + b * u[k - 1]
    y = y + 1e-4 * rng.standard_normal(y.shape)
    settings = candidate_settings({"methods": ["N4SID"], "horizons": [10], "a_stability": [False, True]})
    settings.append({"method": "BOGUS", "ss_f": 10, "ss_p": 10, "A_stability": False, "refine": "auto"})
    c = identify_candidates(u, y, "selfsensing", 1, settings, FS, ["i_ypos"], ["y_ss"])
    assert [x.same_as for x in c[:2]] == [None, "N4SID f10 p10"]
    assert c[2].model is None and "BOGUS" in c[2].error
    assert np.exp(np.log(c[0].model.poles[0].real)) == pytest.approx(a, abs=2e-3)
    reused = identify_candidates(u, y, "selfsensing", 1, settings[:1], FS, ["i_ypos"], ["y_ss"], known=c[:1])
    assert reused[0].model is c[0].model


# --------------------------------------------------------------------------------------
# peak cause on loops with a known cause
# --------------------------------------------------------------------------------------
def _siso_loop(num, den):
    """A discrete (ZOH) SISO system named as the self-sensing channel of the uncertainty loop."""
    d = control.c2d(control.ss(control.tf(num, den)), DT, "zoh")
    return control.ss(d.A, d.B, d.C, d.D, DT, inputs=["d_y_ss"], outputs=["i_ypos"])


def _mu(loop, weights):
    from ssamb.robustness import log_grid, mu_for_case

    return mu_for_case(loop, weights, "selfsensing", log_grid(1.0, 2000.0, 200))


def _resonant_loop(f0: float = 60.0, zeta: float = 0.05):
    """A loop with one lightly damped closed-loop pole pair (f0, zeta) and a fast real pole at 800
    rad/s, a flat unit weight, and its mu sweep: ``(f0, zeta, loop, weights, sweep)``."""
    w0 = 2 * np.pi * f0
    loop = _siso_loop([w0 ** 2 * 800.0], np.polymul([1, 2 * zeta * w0, w0 ** 2], [1, 800.0]))
    weights = {"selfsensing": control.tf([1.0], [1.0])}
    return f0, zeta, loop, weights, _mu(loop, weights)


def test_peak_cause_finds_a_known_lightly_damped_pole():
    from ssamb.peak_cause import peak_cause

    f0, zeta, loop, weights, sweep = _resonant_loop()
    a = 2 * np.pi * 40.0
    plant = IdentifiedModel(np.array([[np.exp(a * DT)]]), np.ones((1, 1)), np.ones((1, 1)), np.zeros((1, 1)), DT,
                            "x", ("i",), ("y",), False)
    pc = peak_cause(loop, weights, "selfsensing", sweep, plant)
    dom = pc["dominant"]
    assert dom["f_hz"] == pytest.approx(f0, rel=1e-6) and dom["zeta"] == pytest.approx(zeta, rel=1e-6)
    assert pc["least_damped"][0]["f_hz"] == pytest.approx(f0, rel=1e-6)
    assert pc["peak_hz"] == pytest.approx(f0 * np.sqrt(1 - 2 * zeta ** 2), rel=5e-3)
    assert pc["cause"] == "closed-loop pole"
    assert pc["dominant"]["mu_drop"] > 0.5  # zeta 0.05 -> 0.15 lowers the resonance ~3x
    assert pc["damped_dominant"]["peak"] < 0.5 * pc["peak"]
    assert pc["at_grid_edge"] is None
    assert pc["plant_critical_hz"] == pytest.approx(40.0, rel=1e-9)
    assert pc["modal_error"] < 1e-8
    assert "60 Hz" in pc["sentence"] and "zeta 0.05" in pc["sentence"]


def _sensor(zero_z: float) -> IdentifiedModel:
    """A self-sensing model i_ypos -> y_ss, (z - zero_z) / ((z - 0.5)(z - 0.9)), with the offset column."""
    d = control.ss(control.tf([1.0, -zero_z], np.polymul([1, -0.5], [1, -0.9]), DT))
    B = np.column_stack([np.asarray(d.B), np.zeros(2)])
    D = np.column_stack([np.asarray(d.D), [0.0]])
    return IdentifiedModel(np.asarray(d.A), B, np.asarray(d.C), D, DT, "x", ("i_ypos",), ("y_ss",), True)


def test_peak_cause_names_a_near_cancellation_with_a_zero_of_the_self_sensing_model():
    from ssamb.peak_cause import peak_cause, sensor_zeros

    f0, zeta, loop, weights, sweep = _resonant_loop()
    z_at = np.exp(-2 * np.pi * 55.0 * DT)  # a real zero at 55 Hz, next to the 60 Hz pole
    zeros, dc = sensor_zeros(_sensor(z_at), DT)
    assert zeros[0]["f_hz"] == pytest.approx(55.0, rel=1e-9)
    assert dc == pytest.approx((1 - z_at) / (0.5 * 0.1), rel=1e-9)
    pc = peak_cause(loop, weights, "selfsensing", sweep, selfsensing=_sensor(z_at))
    assert pc["cause"] == "near-cancellation" and "zero at 55 Hz" in pc["sentence"]
    far = peak_cause(loop, weights, "selfsensing", sweep, selfsensing=_sensor(np.exp(-2 * np.pi * 5.0 * DT)))
    assert far["cause"] == "closed-loop pole"


def test_peak_cause_attributes_a_weight_bump_to_the_weight():
    from ssamb.peak_cause import peak_cause

    wc = 2 * np.pi * 1000.0
    loop = _siso_loop([wc], [1, wc])  # flat to 1 kHz, one real pole: no resonance anywhere
    s = control.tf("s")
    bump = 0.01 * (1 + s / (2 * np.pi * 5)) / ((1 + s / (2 * np.pi * 30)) ** 2)  # |W| largest near 12 Hz
    weights = {"selfsensing": bump}
    pc = peak_cause(loop, weights, "selfsensing", _mu(loop, weights))
    assert pc["cause"] == "weight"
    assert pc["weights"]["selfsensing"]["max_mag_hz"] == pytest.approx(pc["peak_hz"], rel=0.1)
    assert pc["dominant"]["zeta"] == pytest.approx(1.0)
    assert pc["plant_critical_hz"] is None


def test_run_select_files_in_files_out(known, tmp_path):
    from ssamb.config import load_config
    from ssamb.io import save_npz
    from ssamb.model_io import Failed, load_candidates, load_model, save_candidates
    from ssamb.stages.select import run_select

    cands, val = known
    files = {}
    for k, v in cands.items():
        files[k] = tmp_path / f"{k}_candidates.npz"
        save_candidates(files[k], k, v)
    back = load_candidates(files["selfsensing"])
    assert [c.label for c in back] == [c.label for c in cands["selfsensing"]]
    assert back[3].model is None and back[3].error == "RuntimeError: boom" and back[4].same_as == "S f10 p10"
    np.testing.assert_array_equal(back[0].model.B, cands["selfsensing"][0].model.B)
    save_npz(tmp_path / "val.npz", {k: np.asarray(v) for k, v in val.items() if k != "states"})
    outs = {k: tmp_path / f"{k}_loop.npz" for k in cands}
    info = run_select(files, tmp_path / "val.npz", load_config(), outs, tmp_path / "select.json")
    assert not info["failed"] and info["n_combinations"] == 6 and info["n_stable"] == 2
    assert load_model(outs["selfsensing"]).method == "S"
    # no stable combination: every model file is a failed fit that says why
    save_candidates(files["selfsensing"], "selfsensing", cands["selfsensing"][1:3])
    info = run_select(files, tmp_path / "val.npz", load_config(), outs, tmp_path / "select.json")
    assert info["failed"] and "no stable assembled loop" in info["error"]
    for path in outs.values():
        with pytest.raises(Failed, match="smallest spectral radius"):
            load_model(path)


def test_position_path_of_the_known_amplifier(known, pid):
    from ssamb.identification.joint import position_path, position_path_scan

    cands, _ = known
    G = cands["amplifier"][0].model  # i_ypos = wa/(s + wa) (u_y_cmd - 200 y_meas) + bias
    for row in position_path(G, pid, [1.0, 40.0, 300.0]):
        assert row["abs_Gp_a_per_m"] / row["abs_Gu"] == pytest.approx(200.0, rel=1e-6)
        z = np.exp(2j * np.pi * row["f_hz"] * DT)
        ratio = 200.0 / complex(np.squeeze(pid(z)))
        assert complex(*row["Gp_over_minus_GuC"]) == pytest.approx(ratio, rel=1e-6)
    P, S = cands["plant"][0].model, cands["selfsensing"][0].model
    scan = position_path_scan(P, G, S, pid, pid, (0.0, 1.0))
    ref = stability(assemble_closed_loop(P, G, S, pid, pid)).spectral_radius
    assert scan[1]["spectral_radius"] == pytest.approx(ref, abs=1e-12)
    assert scan[0]["spectral_radius"] != pytest.approx(ref, abs=1e-9)


def test_peak_cause_at_the_grid_edge_attributes_the_interior_maximum_too():
    from ssamb.peak_cause import peak_cause

    f0, zeta = 60.0, 0.1
    w0 = 2 * np.pi * f0
    loop = _siso_loop([w0 ** 2], [1, 2 * zeta * w0, w0 ** 2])  # unit DC gain, resonance x5 at 60 Hz
    s = control.tf("s")
    weights = {"selfsensing": 0.01 / (1 + s / (2 * np.pi * 3.0))}  # largest at DC, 1/20 at 60 Hz
    pc = peak_cause(loop, weights, "selfsensing", _mu(loop, weights))
    # at the grid's 1 Hz: |W| |T| = 0.01 / |1 + j/3| (|T(1 Hz)| = 1 to 3e-4)
    assert pc["at_grid_edge"] == "low" and pc["peak"] == pytest.approx(0.01 / np.sqrt(1 + 1 / 9), rel=1e-3)
    assert pc["cause"] == "weight" and pc["dominant"]["mu_drop"] == pytest.approx(0.0, abs=1e-3)
    inner = pc["interior"]
    assert inner["dominant"]["f_hz"] == pytest.approx(f0, rel=1e-6) and inner["cause"] == "closed-loop pole"
    assert "Largest interior maximum" in pc["sentence"]


def test_run_identify_writes_the_candidates_of_the_grid(pid, tmp_path):
    from ssamb.io import save_npz
    from ssamb.model_io import load_candidates
    from ssamb.stages.identify import run_identify

    truth = assemble_closed_loop(*_known_linear_amb(), pid, pid, require_stable=True)
    paths = []
    for name, dur, seed in (("est", 0.06, 1), ("val", 0.03, 3)):
        n = int(dur * FS)
        d = simulate_closed_loop(truth, np.arange(n) * DT, 0.0, 0.0, _pulse_train(n, 0.3, seed),
                                 _pulse_train(n, 0.3, seed + 1), x0=lti_initial_state(truth))
        d.pop("states")
        paths.append(tmp_path / f"{name}.npz")
        save_npz(paths[-1], {**d, "fs_hz": np.asarray(FS)})
    params = {"ss_f": 10, "ss_p": 10, "methods": ["N4SID", "PARSIM-K"], "selection": "loop",
              "order_scan": {"orders": [1], "duration_s": 0.02},
              "selfsensing": {"order": 1, "input": "current"},
              "loop_selection": {"methods": ["N4SID", "PARSIM-K"], "horizons": [10, 12], "a_stability": [False, True]}}
    info = run_identify(*paths, "selfsensing", params, tmp_path / "m.npz", tmp_path / "m.json",
                        out_candidates=tmp_path / "c.npz")
    cands = load_candidates(tmp_path / "c.npz")
    assert [c.label for c in cands] == ["N4SID f10 p10", "N4SID f10 p10 stab", "N4SID f12 p12", "N4SID f12 p12 stab",
                                        "PARSIM-K f10 p10", "PARSIM-K f12 p12"]
    assert info["loop_candidates"]["n"] == 6
    assert all(c.model is not None and c.model.input_names == ("i_ypos",) for c in cands)


def test_identify_refuses_an_experiment_in_which_the_rotor_delevitated(tmp_path):
    from ssamb.io import DataError, save_npz
    from ssamb.stages.identify import run_identify

    n = 200
    cols = {c: np.zeros(n) for c in ("t", "r_x", "r_y", "inj_x", "inj_y", "x_meas", "y_meas", "y_ss", "u_x", "u_y",
                                     "i_ypos", "i_yneg", "i_xpos", "i_xneg")}
    path = tmp_path / "id.npz"
    save_npz(path, {**cols, "fs_hz": np.asarray(FS)}, meta={"delevitation_s": 0.0125})
    params = {"ss_f": 10, "ss_p": 10, "methods": ["N4SID"], "order_scan": {"orders": []},
              "selfsensing": {"order": 1}}
    with pytest.raises(DataError, match=r"delevitated at t = 0.0125 s"):
        run_identify(path, path, "selfsensing", params, tmp_path / "m.npz", tmp_path / "m.json")
    assert not (tmp_path / "m.npz").exists()
