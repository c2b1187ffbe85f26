"""How exactly can a model replay a rig that *is* the model? The floor of close the loop.

    python bench/replay_sensitivity.py [--seconds 1.2] [--perturbation 1e-12]

A rig run (the 30 um, 5-100 Hz multisine on both axes, as the close-the-loop demo excites it)
and its replay (the same model driven by the rig's recorded references and injections, the
way :class:`ssamb.closeloop.replay.Replayer` replays) are compared channel by channel, rms of
the difference over the record after 0.25 s, against the rms of the signal:

1. replay of the identical model (must be 0: the simulator is deterministic);
2. replay with the rotor mass changed by ``--perturbation``, against the replay of the
   identical model (same seed) (relative, 1e-12 by default: far
   below anything a fit could resolve) -- a smooth, stable model moves its output by about
   that fraction; a model whose trajectory depends sensitively on its state does not.

Each comparison runs with the default converters without their analog noise (quantisation and
computation delay in the loop), with ideal converters, and with the default converters' noise and
additive quantisers (``converters.additive_quantisers``: a replay smooth in the parameters for a
fixed seed wherever the loop is not sensitive to its state; the seeds of rig and replay differ, so
the same model's column is the noise there). The close-the-loop statistics treat
what a replay cannot reproduce as signal unless its noise floor is estimated from the data;
the figures printed here are that floor. Nothing is asserted.
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from ssamb.config import apply_overrides, load_config  # noqa: E402
from ssamb.sim import simulate  # noqa: E402

CHANNELS = ("x_meas", "y_meas", "y_ss", "u_x", "u_y", "i_ypos")
UNITS = {"x_meas": ("um", 1e6), "y_meas": ("um", 1e6), "y_ss": ("um", 1e6), "u_x": ("A", 1.0),
         "u_y": ("A", 1.0), "i_ypos": ("A", 1.0)}
QUIET = {"converters.current_noise_a": 0.0, "converters.position_noise_m": 0.0}
IDEAL = {**QUIET, "converters.current_adc_bits": 0, "converters.position_adc_bits": 0}
ADDITIVE = {"converters.additive_quantisers": 1}
EXCITATION = {"kind": "multisine", "point": "position", "axis": "both", "amplitude_m": 3.0e-5, "f_min_hz": 5.0,
              "f_max_hz": 100.0, "f_resolution_hz": 5.0, "periods": 6, "seed": 3}


def _compare(cfg: dict, seconds: float, rel: float) -> dict:
    rig = simulate(cfg, "multisine", duration_s=seconds, excitation=dict(EXCITATION), progress=False)
    arrays = {k: rig.data[k] for k in ("t", "r_x", "r_y", "inj_x", "inj_y")}
    kw = {"arrays": arrays, "start": "levitated", "settle_s": float(cfg["simulation"]["settle_s"]), "progress": False}
    same = simulate(cfg, **kw)
    heavier = apply_overrides(cfg, {"table1.mass_kg": cfg["table1"]["mass_kg"] * (1.0 + rel)})
    pert = simulate(heavier, **kw)
    k0 = int(0.25 * float(rig.data["fs_hz"]))
    out = {}
    for c in CHANNELS:
        sig = np.std(rig.data[c][k0:])
        out[c] = (sig, np.std((rig.data[c] - same.data[c])[k0:]), np.std((same.data[c] - pert.data[c])[k0:]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.2)
    ap.add_argument("--perturbation", type=float, default=1e-12, help="relative change of the rotor mass")
    args = ap.parse_args()
    base = load_config()
    print(f"rig vs replay, {args.seconds:g} s of the 30 um 5-100 Hz multisine on both axes; rms after 0.25 s")
    for label, ov in (("default converters, no analog noise", QUIET), ("ideal converters", IDEAL),
                      ("default converters with their noise, additive quantisers (rig and replays)", ADDITIVE)):
        cfg = apply_overrides(base, ov)
        res = _compare(cfg, args.seconds, args.perturbation)
        print(f"\n{label}")
        print(f"  {'channel':8s}{'signal':>12s}{'same model':>14s}{f'mass x (1+{args.perturbation:g})':>24s}")
        for c, (sig, d0, d1) in res.items():
            u, s = UNITS[c]
            print(f"  {c:8s}{sig * s:>10.4g} {u:2s}{d0 * s:>11.3g} {u:2s}{d1 * s:>12.3g} {u:2s}"
                  f" ({100 * d1 / sig:.3g} % of the signal)")


if __name__ == "__main__":
    from ssamb import pin_blas_threads

    pin_blas_threads()
    main()
