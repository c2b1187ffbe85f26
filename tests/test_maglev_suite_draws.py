"""The ball's randomized suite (``bench/maglev_suite.py``): how a draw's rig is drawn again."""
import numpy as np
import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def suite():
    mod = bench_module("maglev_suite")
    from ssamb.closeloop.settings import settings_from_config
    from ssamb.device import get_device

    dev = get_device("maglev1d")
    cfg = dev.default_config()
    names, _ = mod.drawable(dev, cfg, settings_from_config(cfg, dev))
    return mod, names, mod._center(dev, cfg, None)


@pytest.mark.slow
def test_a_draw_is_redrawn_until_a_rig_levitates_and_a_cap_leaves_it_without_data(suite):
    """A draw whose recording and effect levitate rarely (an actuation delay on multiescalon's
    steps) has no rig within a small cap -- reported without data, with the cap and the refused
    rigs' reasons -- and has one within the suite's cap; a draw that had its rig within the small
    cap keeps the same rig and data under the larger one (the same random stream: raising the cap
    changes only the draws the small cap left without data)."""
    mod, names, center = suite
    seed = 20261126
    few = mod.make_draw(3, True, seed, center, names, attempts=20)
    assert few["data"] is None and few["failure"].endswith("in 20 draws")
    assert few["refused"].get("its data touch a stop", 0) > 0
    many = mod.make_draw(3, True, seed, center, names, attempts=mod.ATTEMPTS)
    assert many["data"] is not None and sum(many["refused"].values()) > sum(few["refused"].values())
    a, b = (mod.make_draw(5, True, seed, center, names, attempts=n) for n in (20, mod.ATTEMPTS))
    assert a["data"] is not None and a["ov"] == b["ov"] and a["true"] == b["true"]
    for c in ("y", "i", "u"):
        np.testing.assert_array_equal(a["data"][c], b["data"][c])
