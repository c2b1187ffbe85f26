"""When does the nonlinear model delevitate in the 99 um sweep? A scan over the open assumptions
of the paper's rig (config scenarios.paper_rig): the rotor weight's share on this bearing and the
sweep's duration, with 50 turns per electromagnet, over a few noise seeds.

    python bench/rig_sweep.py [--shares 0.35 0.4 0.45 0.5] [--durations 0.5 0.55 0.6] [--seeds 3]

Prints, per (share, duration), the delevitation time and the sweep frequency there for each seed
(none: the rotor held), with the load average (the machine may be shared). Nothing is asserted:
it is the evidence behind the values scenarios.paper_rig chooses.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from ssamb.config import apply_overrides, load_config  # noqa: E402
from ssamb.signals import sweep_frequency_at  # noqa: E402
from ssamb.sim import simulate  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--shares", type=float, nargs="+", default=[0.35, 0.4, 0.45, 0.5])
    ap.add_argument("--durations", type=float, nargs="+", default=[0.5, 0.55, 0.6])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--turns-per-magnet-coils", type=int, default=1, help="geometry.coils_per_magnet")
    args = ap.parse_args()
    cfg0 = load_config(ROOT / "config.yaml")
    print(f"load average {os.getloadavg()[0]:.2f}; coils per magnet {args.turns_per_magnet_coils}")
    print(f"{'share':>6s} {'sweep (s)':>9s}  delevitation time (s) @ sweep frequency (Hz), one per seed")
    for share in args.shares:
        for T in args.durations:
            t0, cells = time.perf_counter(), []
            for k in range(args.seeds):
                cfg = apply_overrides(cfg0, {"geometry.coils_per_magnet": args.turns_per_magnet_coils,
                                             "weight_share": share, "seed": cfg0["seed"] + k,
                                             "experiments.sweep.duration_s": T,
                                             "experiments.sweep.excitation.sweep_duration_s": T})
                exc = cfg["experiments"]["sweep"]["excitation"]
                td = simulate(cfg, "sweep", progress=False).meta["delevitation_s"]
                f = None if td is None else float(sweep_frequency_at([td], exc["f_start_hz"], exc["f_stop_hz"], T,
                                                                     exc.get("law", "linear"))[0])
                cells.append("none" if td is None else f"{td:.3f} @ {f:.1f}")
            print(f"{share:6.2f} {T:9.2f}  " + ", ".join(cells) + f"   ({time.perf_counter() - t0:.1f} s)", flush=True)


if __name__ == "__main__":
    main()
