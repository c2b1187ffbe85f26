"""The simulator's bits do not depend on numba's cache: a kernel compiled in the running process
and the same kernel loaded from the cache give identical data (``ssamb.sim.magnetics.FASTMATH``).

With all of numba's fastmath flags the two parted at round-off on 7 of 12 randomized rigs, and
the self-sensed loop grew the difference into another noise realisation (README, Simulator
notes). The test runs the same rigs and replays in two fresh processes sharing an empty
``NUMBA_CACHE_DIR``: the first compiles, the second loads.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

TESTS = Path(__file__).resolve().parent

SCRIPT = r"""
import hashlib, pathlib, sys, tempfile
import numpy as np
sys.path.insert(0, sys.argv[1])
import test_closeloop_effects as T
from ssamb.config import load_config
from ssamb.rig import SUITE_EFFECTS, draw_effect, draw_perturbation
from ssamb.sim.device import record_from_arrays
from ssamb.sim import simulate
cfg = load_config()
out = []
for k in (1, 2, 5):          # suite draws whose data parted between the two paths before
    rng = np.random.default_rng([T.SEED, 13, k])
    ov, _ = draw_perturbation(rng, cfg)
    true = draw_effect(SUITE_EFFECTS[int(rng.integers(len(SUITE_EFFECTS)))], rng)
    seed = int(rng.integers(1, 10_000))
    arrays, meta, _ = T.rig(pathlib.Path(tempfile.mkdtemp()), [true], ov, name=f"d{k}",
                            exc={**T.EXC, "seed": seed}, noise={**T.NOISE, "seed": seed + 1})
    rec = record_from_arrays(arrays, meta, float(cfg["controller"]["fs_hz"]), "x")
    res = simulate(cfg, arrays={c: v[:rec.n] for c, v in rec.inputs.items()}, start=rec.start,
                   settle_s=rec.settle_s, progress=False, seed=8, calibration_noise=False)
    h = hashlib.sha1(arrays["x_meas"].tobytes() + arrays["y_meas"].tobytes())
    for c in sorted(res.data):
        if isinstance(res.data[c], np.ndarray):
            h.update(res.data[c].tobytes())
    out.append(h.hexdigest())
print(" ".join(out))
"""


def _run(cache: Path) -> list:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    res = subprocess.run([sys.executable, "-c", SCRIPT, str(TESTS)], env=env, capture_output=True, text=True,
                         timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout.split()


def test_a_kernel_compiled_here_and_one_loaded_from_the_cache_give_the_same_bits(tmp_path):
    compiled = _run(tmp_path)
    assert any(tmp_path.rglob("*.nbc")), "the first run did not write numba's cache"
    loaded = _run(tmp_path)
    assert len(compiled) == 3 and compiled == loaded
