r"""``external_force``: an arbitrary force on the rotor, for tests.

Physics: :math:`(F_x(t), F_y(t))` from a CSV file (columns ``t, fx_n, fy_n``) or from arrays,
linearly interpolated at the simulator's samples. Close the loop does not look for it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ._common import EffectError

NAME = "external_force"
REQUIRED = ()
OPTIONAL = ("file", "t", "fx_n", "fy_n")
SIGNATURE = "an arbitrary force (a test tool; not searched)"
SEARCHABLE = False
NEEDS_HINT = True
ORDER = 99


def validate(p: dict, where: str) -> dict:
    if "file" not in p and not all(k in p for k in ("t", "fx_n", "fy_n")):
        raise EffectError(f"{where}: give 'file' (CSV with t, fx_n, fy_n) or arrays t, fx_n, fy_n")
    return p


def apply(e: dict, ov: dict, f_x, f_y, t, base_dir) -> None:
    if "file" in e:
        path = Path(e["file"])
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        if not path.exists():
            raise EffectError(f"effect 'external_force': file '{path}' not found")
        tab = np.genfromtxt(path, delimiter=",", names=True)
        missing = [c for c in ("t", "fx_n", "fy_n") if c not in (tab.dtype.names or ())]
        if missing:
            raise EffectError(f"effect 'external_force': file '{path}' lacks column(s) {', '.join(missing)}")
        te, fxe, fye = tab["t"], tab["fx_n"], tab["fy_n"]
    else:
        te, fxe, fye = (np.asarray(e[k], float) for k in ("t", "fx_n", "fy_n"))
    f_x += np.interp(t, te, fxe)
    f_y += np.interp(t, te, fye)


def evidence(ft, alpha: float, st) -> dict:
    return {"score": 0.0, "log10_p": 0.0, "significant": False, "hints": {}, "details": {}}


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return 0.0


def model(hints: dict, record, st) -> str:
    return "an arbitrary force is a test tool, not a library effect"


def report(m, theta, se, significant) -> list[dict]:
    return []
