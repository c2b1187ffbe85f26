"""The levitated ball as a close-the-loop device: config, records, the controller check, replay."""
import pickle
import re
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from ssamb.config import ConfigError
from ssamb.device import Device, get_device
from ssamb.io import DataError
from ssamb.maglev1d import controller
from ssamb.maglev1d.config import load_config

ROOT = Path(__file__).resolve().parent.parent
DATA = {p.stem.split("_")[1]: p for p in sorted((ROOT / "resources" / "maglev1d").glob("dataset_*.npz"))}
DEV = get_device("maglev1d")
CFG = DEV.default_config()


def _record(name):
    arrays, meta = DEV.load(DATA[name])
    DEV.validate(arrays, str(DATA[name]))
    return DEV.record(arrays, meta, CFG, str(DATA[name]))


def test_registered_device():
    assert isinstance(DEV, Device) and DEV.name == "maglev1d"
    assert DEV.channels == ("y", "i", "u") and all(DEV.unit(c) for c in DEV.channels)
    for key in DEV.priors(CFG):
        node = CFG
        for part in key.split("."):
            node = node[part]
        assert isinstance(node, float)


def test_every_config_value_has_a_reason_and_units():
    text = resources.files("ssamb.maglev1d").joinpath("config.yaml").read_text()
    for line in text.splitlines():
        m = re.match(r"\s*([\w.]+):\s*([^#\s][^#]*?)\s*(#.*)?$", line)
        if m and m.group(2):
            assert m.group(3), f"no reason: {line}"


def test_config_errors_name_the_key(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("ball: {mass_kg: -1}\n")
    with pytest.raises(ConfigError, match=r"c.yaml: key 'ball.mass_kg'"):
        load_config(p)
    p.write_text("ball: {weight_kg: 1}\n")
    with pytest.raises(ConfigError, match=r"key 'ball.weight_kg': unknown"):
        load_config(p)
    p.write_text("closeloop: {calibration: {ball.colour: 0.1}}\n")
    with pytest.raises(ConfigError, match=r"closeloop.calibration.ball.colour"):
        load_config(p)
    p.write_text("coil: {r_ohm: 3.0}\n")
    assert load_config(p)["coil"]["r_ohm"] == 3.0 and load_config(p)["ball"]["mass_kg"] == CFG["ball"]["mass_kg"]


@pytest.mark.parametrize("name", ["constante", "escalon", "multiescalon"])
def test_controller_reproduces_logged_command(name):
    arrays, _ = DEV.load(DATA[name])
    res = controller.check(arrays, CFG)
    assert res["within_rounding"] == 1.0 and res["rms_v"] < 5e-5


@pytest.mark.parametrize("name", ["senoidal", "chirp"])
def test_controller_reproduces_command_with_the_references_formula(name):
    """The log writes a moving reference rounded to 1 um; its formula (5 mm + 1 mm sin(2 pi 0.3 s)
    and 5 mm + 0.8 mm sin(2 pi (0.1 s + 0.03 s^2)), s = t - 5 s) gives the command exactly."""
    arrays, _ = DEV.load(DATA[name])
    tau = np.arange(len(arrays["t"])) * 0.01 - 5.0
    if name == "senoidal":
        x = 1e-3 * np.sin(2 * np.pi * 0.3 * tau)
    else:
        x = 0.8e-3 * np.sin(2 * np.pi * (0.1 * tau + 0.03 * tau ** 2))
    yd = 5e-3 + np.where(tau > 0, x, 0.0)
    np.testing.assert_allclose(yd, arrays["yd"], atol=0.5e-6 + 1e-12)
    assert controller.check(arrays, CFG, yd=yd)["within_rounding"] == 1.0
    assert controller.check(arrays, CFG)["within_rounding"] < 1.0


@pytest.mark.parametrize("name", sorted(DATA))
def test_record_usable_stretches_levitate(name):
    rec = _record(name)
    assert rec.usable and rec.channels["y"].shape == (rec.n,)
    y = rec.channels["y"]
    for a, b in rec.usable:
        assert b - a >= 100
        assert np.all(y[a:b] >= CFG["levitation"]["margin_m"]) and np.all(y[a:b] <= CFG["stops"]["bottom_m"] - 1e-3)
    assert not DEV.measured_contact(rec, CFG, None)


def test_replay_deterministic_seeded_and_pickles():
    rec = _record("escalon")
    a = DEV.replay(CFG, rec, [], rec.n, 5)
    b = pickle.loads(pickle.dumps(DEV)).replay(CFG, rec, [], rec.n, 5)
    c = DEV.replay(CFG, rec, [], rec.n, 6)
    for ch in DEV.channels:
        np.testing.assert_array_equal(a.channels[ch], b.channels[ch])
    assert not np.array_equal(a.channels["i"], c.channels["i"])
    short = DEV.replay(CFG, rec, [], 1000, 5)
    assert len(short.channels["u"]) == 1000
    np.testing.assert_array_equal(short.channels["u"], a.channels["u"][:1000])
    # outside the usable stretches the replay returns the record's own samples
    a0 = rec.usable[0][0]
    np.testing.assert_array_equal(a.channels["y"][:a0], rec.channels["y"][:a0])
    assert DEV.replay(CFG, rec, [], rec.n, None).channels["y"].shape == (rec.n,)


def test_additive_replay_is_smooth_in_the_parameters_for_a_seed():
    """A seeded replay with additive quantisers moves by a tiny amount for a tiny change of a
    parameter; a rounded one flips counts, and the loop makes another realisation of it."""
    from ssamb.config import apply_overrides

    rec = _record("constante")
    a0 = rec.usable[0][0]
    start = apply_overrides(CFG, DEV.initial_estimate(rec, CFG))      # the published model drops the ball
    out = {}
    for add in (0, 1):
        cfg = {**start, "replay": {**start["replay"], "additive_quantisers": add}}
        moved = {**cfg, "magnet": {**cfg["magnet"], "k_h": cfg["magnet"]["k_h"] * (1 + 1e-7)}}
        r0, r1 = (DEV.replay(c, rec, [], rec.n, 7) for c in (cfg, moved))
        assert not r0.contact and not r1.contact
        out[add] = float(np.max(np.abs(r1.channels["y"][a0:] - r0.channels["y"][a0:])))
    q = controller.position_lsb_m(CFG)
    assert out[1] < 1e-3 * q
    assert out[0] >= q


def test_rig_data_round_to_the_adcs_counts():
    yd = np.full(300, 0.005)
    cfg = {**CFG, "amplifier": {**CFG["amplifier"], "v_max_v": 4.85}}
    log = DEV.simulate_log(cfg, yd, seed=3)
    q = controller.position_lsb_m(CFG)
    np.testing.assert_allclose(log["y"] / q, np.round(log["y"] / q), atol=1e-9)


def test_start_candidates_are_the_one_level_family_through_the_start():
    """Every candidate keeps the start's equilibrium current and gap-dependent inductance at the
    mean reading of the compared parts (with the start's zero), its sensor scale on a grid of a
    quarter tolerance up to two about the start's; a start without the scale gives none."""
    from ssamb.maglev1d.physics import equilibrium_current_a, inductance_h

    rec = _record("constante")
    start = {"sensors.position_gain": 0.9, "magnet.a_m": 0.004, "magnet.k_h": 0.04, "sensors.position_offset_m": 2e-4,
             "amplifier.v_max_v": 5.0}
    cands = DEV.start_candidates(rec, CFG, start)
    lev = np.concatenate([rec.channels["y"][a:b] for a, b in rec.usable])
    y_read = float(np.mean(lev)) - start["sensors.position_offset_m"]
    b = CFG["ball"]

    def at_level(c):
        y = y_read / c["sensors.position_gain"]
        return (equilibrium_current_a(y, b["mass_kg"], b["gravity_m_per_s2"], c["magnet.k_h"], c["magnet.a_m"]),
                inductance_h(y, 0.0, c["magnet.k_h"], c["magnet.a_m"]))
    tol = CFG["closeloop"]["calibration"]["sensors.position_gain"]
    steps = sorted(round((c["sensors.position_gain"] - 0.9) / (0.25 * tol), 9) for c in cands)
    from ssamb.maglev1d.device import one_level_family

    for x in (x for x in range(-8, 9) if x != 0):        # every grid member whose law keeps a length
        a2, _ = one_level_family(0.004, 0.04, 0.9, 0.9 + 0.25 * x * tol, y_read)
        assert (x in steps) == (a2 > 0)
    assert len(steps) >= 12
    for c in cands:
        assert at_level(c) == pytest.approx(at_level(start), rel=1e-12)
        assert c["amplifier.v_max_v"] == 5.0 and c["sensors.position_offset_m"] == 2e-4
    assert DEV.start_candidates(rec, CFG, {"magnet.a_m": 0.004, "magnet.k_h": 0.04}) == []


def _levitating_arrays(n=400, scale=1.0):
    t = np.arange(n) * 0.01
    return {"t": t, "y": np.full(n, 0.005) * scale, "i": np.full(n, 0.45), "u": np.full(n, 7.0),
            "yd": np.full(n, 0.005) * scale}


def test_validate_accepts_levitation_and_rejects_a_ball_that_never_floats():
    DEV.validate(_levitating_arrays(), "ok.csv")
    a = _levitating_arrays()
    a["y"][:] = CFG["stops"]["bottom_m"]
    with pytest.raises(DataError, match=r"bad.csv: column 'y': the ball never levitates"):
        DEV.validate(a, "bad.csv")
    a = _levitating_arrays()
    a["i"][:] = 0.02                                  # floating without current: held by hand
    with pytest.raises(DataError, match="never levitates"):
        DEV.validate(a, "bad.csv")
    with pytest.raises(DataError, match="in mm"):
        DEV.validate(_levitating_arrays(scale=1000.0), "mm.csv")


def test_record_rejects_a_ball_that_never_follows_its_reference():
    a = _levitating_arrays()
    a["yd"][:] = 0.012                                # 7 mm away the whole time
    DEV.validate(a, "far.csv")
    with pytest.raises(DataError, match=r"far.csv: column 'y': the ball levitates but never stays"):
        DEV.record(a, {}, CFG, "far.csv")


def test_notes_flag_units():
    a = _levitating_arrays()
    a["i"] = a["i"] * 1000
    assert any("mA" in s for s in DEV.notes(a, {}, CFG))


def test_cli_style_csv_end_to_end(tmp_path):
    """A user's CSV with the columns t,y,i,u,yd (and an extra one) loads, validates and records."""
    arrays, _ = DEV.load(DATA["constante"])
    p = tmp_path / "rig.csv"
    cols = ["t", "y", "i", "u", "yd"]
    rows = np.c_[[arrays[c] for c in cols]].T
    p.write_text("t,y,i,u,yd,temperature_c\n" + "".join(",".join(repr(float(v)) for v in r) + ",21\n" for r in rows))
    a2, m2 = DEV.load(p)
    DEV.validate(a2, str(p))
    rec = DEV.record(a2, m2, CFG, str(p))
    assert rec.usable == _record("constante").usable


def test_checks_published_against_start():
    arrays, _ = DEV.load(DATA["escalon"])
    pub = DEV.checks(arrays, CFG)
    assert pub["command_per_current"]["measured_ohm"] > 1.5 * pub["command_per_current"]["model_ohm"]
    assert not pub["linearised_loop"]["model_stable"]
    import copy

    cfg = copy.deepcopy(CFG)
    for k, v in DEV.initial_estimate(_record("escalon"), CFG).items():
        sec, key = k.split(".")
        cfg[sec][key] = v
    st = DEV.checks(arrays, cfg)
    loop = st["linearised_loop"]
    at_refs = [r for lv, r in zip(loop["levels_m"], loop["spectral_radius"]) if lv >= 0.004 - 1e-9]
    assert len(at_refs) == 2 and max(at_refs) < 1.0          # stable at the references, 4 and 5 mm
    assert loop["levels_m"][0] < 0.003 and not loop["model_stable"]   # not at the lowest reading it recovers from
    assert st["command_per_current"]["measured_ohm"] == pytest.approx(st["command_per_current"]["model_ohm"], rel=1e-6)
    assert abs(st["equilibrium_current"]["measured_a"] / st["equilibrium_current"]["model_a"] - 1) < 0.03


def test_checks_read_the_current_at_rest_and_the_ball_at_the_face():
    """The current read after 0.2 s of zero command is the sensor's zero (the shipped logs read
    7-12 counts, 15-25 mA); a ball held at the face reads the ADC's 0; every check has a summary."""
    from ssamb.maglev1d import checks as K

    n = 200
    a = {"t": np.arange(n) * 0.01, "y": np.full(n, 0.0), "i": np.full(n, 0.3), "u": np.full(n, 3.0),
         "yd": np.full(n, 0.005)}
    a["u"][50:120] = 0.0
    a["i"][50:120] = 8 * 5 / 2.2 / 1023
    r = K.current_at_rest(a, CFG)
    assert r["samples"] == 120 - 50 - 19 and r["current_a"] == pytest.approx(8 * 5 / 2.2 / 1023)
    f = K.face_reading(a, CFG)
    assert f["samples"] > 0 and f["reading_m"] == 0.0 and f["clipped"]
    for name in DATA:
        arrays, _ = DEV.load(DATA[name])
        for key, c in DEV.checks(arrays, CFG).items():
            assert isinstance(c["summary"], str) and c["summary"], (name, key)
        r = K.current_at_rest(arrays, CFG)
        assert 0.010 < r["current_a"] < 0.030, name


def test_notes_say_when_the_logged_command_does_not_follow_from_the_controller():
    """A log whose command is not the rig controller's (here scaled by 0.8) gets a note; the
    shipped step log, which the controller reproduces, gets none."""
    arrays, meta = DEV.load(DATA["escalon"])
    assert not any(n.startswith("u:") for n in DEV.notes(arrays, meta, CFG))
    a = dict(arrays)
    a["u"] = 0.8 * arrays["u"]
    assert any(n.startswith("u: the logged command follows") for n in DEV.notes(a, meta, CFG))


def test_start_estimate_puts_the_face_where_the_rig_reads_it():
    """The force law's length and the sensor's zero are one quantity to a levitated ball
    (:func:`ssamb.maglev1d.checks.face_anchored`): moving the zero to the face's reading and the
    length with it replays the levitated stretches unchanged; the start estimate's model puts the
    face at the reading the ball stuck there shows (the ADC's 0), not 1.5 mm into the range."""
    import copy

    from ssamb.maglev1d import checks as K
    from ssamb.maglev1d import physics as P

    rec = _record("escalon")
    est = {"sensors.position_gain": 0.81, "sensors.position_offset_m": 0.0015, "amplifier.v_max_v": 4.86,
           "amplifier.drop_v": 1.25, "magnet.k0_h": 0.063}
    anchored = K.face_anchored(est, CFG)
    assert anchored["sensors.position_offset_m"] == 0.0
    assert anchored["magnet.a_m"] == pytest.approx(0.0052 - 0.0015 / 0.81)
    assert anchored["magnet.k_h"] * anchored["magnet.a_m"] == pytest.approx(0.0327 * 0.0052)

    def cfg_of(ov):
        c = copy.deepcopy(CFG)
        for k, v in ov.items():
            sec, key = k.split(".")
            c[sec][key] = v
        return c

    one, two = (DEV.replay(cfg_of(ov), rec, [], rec.n, None) for ov in (est, anchored))
    a, b = rec.usable[0]
    for c, q in (("y", 0.05 / 1023), ("i", 5 / 2.2 / 1023)):
        # the same loop: the quantised loop's flicker decorrelates the samples, its mean and spread stay
        x1, x2 = one.channels[c][a:b], two.channels[c][a:b]
        assert abs(np.mean(x1) - np.mean(x2)) < 0.2 * q and np.std(x1) == pytest.approx(np.std(x2), rel=0.1), c
    assert not one.contact and not two.contact
    start = cfg_of(DEV.initial_estimate(rec, CFG))
    assert abs(P.reading_m(P.knobs_of(start), 0.0)) < 0.05 / 1023


def test_parameters_outside_the_physical_ranges_are_named():
    """A negative stage drop is no rig (a fit treats it as infeasible): the reason names the key;
    the nominal model is physical."""
    from ssamb.config import apply_overrides

    dev = get_device("maglev1d")
    cfg = dev.default_config()
    assert dev.physical(cfg) is None
    assert "amplifier.drop_v" in dev.physical(apply_overrides(cfg, {"amplifier.drop_v": -0.5}))


def test_the_sensor_zero_cannot_put_the_face_where_the_ball_floated():
    """The sensor's zero (the reading at the magnet's face) is limited to the lowest reading of the
    compared parts, or of the ball held at the face, plus three standard deviations of a reading:
    escalon never shows the ball at the face (its lowest levitated reading sets it), constante
    does (clipped at the ADC's 0)."""
    from ssamb.maglev1d.checks import face_reading

    sd = np.hypot(CFG["noise"]["position_m"], controller.position_lsb_m(CFG) / np.sqrt(12))
    for name in ("escalon", "constante"):
        rec = _record(name)
        y = rec.channels["y"]
        low = min(float(np.min(y[a:b])) for a, b in rec.usable)
        f = face_reading({**rec.channels, "yd": rec.inputs["yd"]}, CFG)
        if f["samples"]:
            low = min(low, f["reading_m"])
        lo, hi = DEV.calibration_bounds(rec, CFG)["sensors.position_offset_m"]
        assert lo is None and hi == pytest.approx(low + 3 * sd)
    assert DEV.calibration_bounds(_record("escalon"), CFG)["sensors.position_offset_m"][1] > 1e-3
    assert DEV.calibration_bounds(_record("constante"), CFG)["sensors.position_offset_m"][1] < 1e-4


def test_what_one_level_cannot_tell_and_a_start_that_floats_stays():
    """Along one_level_family the equilibrium current and the gap-dependent inductance at the
    level are those of the model it starts from (the data at one level cannot tell them apart);
    constante's start, whose replays float, keeps its nominal sensor scale."""
    from ssamb.maglev1d.checks import start_estimate
    from ssamb.maglev1d.device import one_level_family
    from ssamb.maglev1d.physics import equilibrium_current_a, inductance_h

    b = CFG["ball"]
    y_read, a, k = 0.005, 0.004, 0.04
    for g0, g in ((1.0, 0.7), (0.8, 1.2)):
        a2, k2 = one_level_family(a, k, g0, g, y_read)
        same = [(equilibrium_current_a(y_read / gs, b["mass_kg"], b["gravity_m_per_s2"], kk, aa),
                 inductance_h(y_read / gs, 0.0, kk, aa)) for gs, aa, kk in ((g0, a, k), (g, a2, k2))]
        assert same[1] == pytest.approx(same[0], rel=1e-12)
    rec = _record("constante")
    est = start_estimate({**rec.channels, "yd": rec.inputs["yd"]}, CFG)
    assert "sensors.position_gain" not in est and DEV._levitating_gain(rec, CFG, est) == est


@pytest.mark.parametrize("effects", [[], [{"name": "saturation", "coefficient_per_a2": 0.6},
                                          {"name": "current_offset", "offset_a": 0.02}]])
def test_balanced_rig_holds_the_ball_with_the_recorded_current_and_command(effects):
    from ssamb.config import apply_overrides
    from ssamb.maglev1d import physics

    rec = _record("senoidal")                       # two usable parts
    cfg = apply_overrides(CFG, {"magnet.a_m": 0.004, "amplifier.drop_v": 1.0, "sensors.position_gain": 0.9})
    ov = DEV.balanced(cfg, rec, effects)
    p = physics.knobs_of(apply_overrides(cfg, ov), DEV.knobs(cfg, effects))
    ioff = p[physics.knob_index("current_offset_a")]
    li, lu = [], []
    for a, b in rec.usable:
        y, i, u = (float(np.mean(rec.channels[c][a:a + 30])) for c in ("y", "i", "u"))
        _, ieq, ueq = physics.equilibrium(p, y)
        li.append(np.log((ieq + ioff) / i))
        lu.append(np.log(ueq / u))
    assert len(li) == 2 and abs(np.mean(li)) < 1e-6 and abs(np.mean(lu)) < 1e-6
    assert max(abs(x) for x in li + lu) < 0.05          # the two parts' balances agree within 5 %
    # without the balance this model is off by more than that
    p0 = physics.knobs_of(cfg, DEV.knobs(cfg, effects))
    a = rec.usable[0][0]
    assert abs(np.log((physics.equilibrium(p0, float(np.mean(rec.channels["y"][a:a + 30])))[1] + ioff)
                      / np.mean(rec.channels["i"][a:a + 30]))) > 0.05


def test_rig_log_starts_each_stretch_from_the_state_its_own_log_gives():
    """A rig's log on a recording with two levitated stretches (a rig of the randomized suite, its
    coil warming): the rig's own model, replayed from that log as the analysis replays it (the
    controller's state reconstructed from the log), follows the second stretch from its start.
    Started from the recording's controller state instead, the log begins that stretch with a
    transient of many position counts that no replay from the log reproduces. The first stretch,
    with one seed, is the same either way."""
    from ssamb.config import apply_overrides
    from ssamb.maglev1d.device import RIG_STREAM

    arrays, meta = DEV.load(DATA["chirp"])
    rec = DEV.record(arrays, meta, CFG, "chirp")
    cfg = apply_overrides(CFG, {"magnet.k_h": 0.04856, "magnet.k0_h": 0.08798, "magnet.a_m": 0.003714,
                                "amplifier.v_max_v": 6.207, "amplifier.drop_v": 2.148,
                                "sensors.position_gain": 0.7422, "sensors.position_offset_m": 9.07e-05})
    rig = {**cfg, "replay": {**cfg["replay"], "additive_quantisers": 0}}
    eff = [{"name": "resistance_drift", "rate_ohm_per_s": 0.0126}]
    (a0, b0), (a, _) = rec.usable
    q = controller.position_lsb_m(CFG)
    own, theirs = DEV.rig_log(rig, rec, eff, 5), DEV.replay(rig, rec, eff, rec.n, 5, RIG_STREAM)
    np.testing.assert_array_equal(own.channels["y"][a0:b0], theirs.channels["y"][a0:b0])
    offset = {}
    for name, out in (("own", own), ("recording's", theirs)):
        assert not out.contact
        data = {**arrays, **out.channels}
        drawn = DEV.record(data, meta, CFG, "rig")
        assert drawn.usable[1][0] == a
        pred = np.mean([DEV.replay(cfg, drawn, eff, rec.n, s).channels["y"] for s in range(4)], axis=0)
        offset[name] = abs(float(np.mean(data["y"][a:a + 50] - pred[a:a + 50])))
    assert offset["own"] < 0.5 * q and offset["recording's"] > 5 * q


@pytest.mark.parametrize("name", ["escalon", "constante"])
def test_a_replay_never_repeats_the_noise_of_a_rig_simulated_with_its_seed(name):
    """A simulated rig (the start's parameters, seed 4) and the model's replays of its log with
    seeds 4 and 5: the replay with the rig's seed is as far from the rig's data on every channel
    as the one with another seed (its noise is its own stream, :data:`REPLAY_STREAM`), not
    closer by sharing the rig's noise (its residual would then be the rounding alone, about 0.6
    of an independent replay's)."""
    from ssamb.config import apply_overrides

    rec = _record(name)
    cfg = apply_overrides(CFG, DEV.initial_estimate(rec, CFG))        # the published model drops the ball
    rig = {**cfg, "replay": {**cfg["replay"], "additive_quantisers": 0}}
    log = DEV.rig_log(rig, rec, [], 4)
    assert not log.contact
    arrays, meta = DEV.load(DATA[name])
    data = {**arrays, **log.channels}
    drawn = DEV.record(data, meta, CFG, "rig")
    mask = np.zeros(drawn.n, bool)
    for a, b in drawn.usable:
        mask[a:b] = True
    reps = {s: DEV.replay(cfg, drawn, [], drawn.n, s) for s in (4, 5)}
    for c in DEV.channels:
        rms = {s: float(np.sqrt(np.mean((r.channels[c] - data[c])[mask] ** 2))) for s, r in reps.items()}
        assert rms[4] > 0.85 * rms[5] > 0, (c, rms)
