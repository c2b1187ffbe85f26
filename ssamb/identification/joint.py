r"""Joint selection: choose the subsystem models by the *assembled* loop (paper section 3).

The paper identifies the plant, the amplifier and the self-sensing module separately and
assembles them into one closed loop (Fig. 3). Its structure (4-input amplifier, self-sensing
from the coil current ``i_ypos``) makes the assembled loop's y axis depend on a split that
closed-loop data do not determine: the controller sees the rotor only through the amplifier's
position path :math:`G_p` and the self-sensing model :math:`S`. For one axis (scalar
transfer functions, plant :math:`P`, command path :math:`G_u`, controller :math:`C`) the
assembled loop's characteristic equation is

.. math:: 1 + C\,G_u\,S - P\,G_p = 0,

so with the physically small :math:`G_p` of a current-controlled amplifier the plant's unstable
pole :math:`\sqrt{k_s/m}` survives; a stable assembled loop needs the identified :math:`G_p` to
carry the position feedback. Which models do that is decided by the method, horizons and
stability option of the identification, not by the physics, and a model that is best for its
own subsystem can make the assembled loop unstable. The paper's assembled loop was stable (its
Fig. 4 fits, 93.76 % and 50.76 %, exist), so its authors must have kept the combination that
gave a stable loop.

This module makes that choice explicit and reproducible: candidates per subsystem
(:func:`candidate_settings`, :func:`identify_candidates`) are assembled in every combination
with the one builder :func:`ssamb.closed_loop.assemble_closed_loop`; each combination is scored
by its spectral radius and by the fit of its replay on an independent validation record
(:func:`ssamb.closed_loop.replay_fits`), both axes; :func:`select_loop` keeps the stable
combination of the best mean fit and returns the whole evidence table.
"""
from __future__ import annotations

import hashlib
import itertools
import warnings
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from ..io import DataError
from .memo import identification_memo
from .model import IdentifiedModel
from .selection import STABLE_SUBSYSTEMS
from .subspace import identify

__all__ = ["Candidate", "LoopSelection", "candidate_settings", "identify_candidates", "score_loop",
           "select_loop", "position_path", "position_path_scan"]

#: SIPPY methods for which ``SS_A_stability`` has an effect (the PARSIM family ignores it).
_A_STABILITY_METHODS = ("N4SID", "MOESP", "CVA")
#: validation channels scored (both axes of Fig. 4)
AXES = ("x_meas", "y_meas")


@dataclass(frozen=True)
class Candidate:
    """One candidate model of a subsystem and the identification settings that made it.

    ``model`` is None when the identification failed (``error`` says why); ``same_as`` names
    an earlier candidate with identical matrices (e.g. ``A_stability`` on an already stable A).
    """

    subsystem: str
    settings: Mapping
    model: IdentifiedModel | None
    error: str | None = None
    same_as: str | None = None

    @property
    def label(self) -> str:
        """``METHOD f<ss_f> p<ss_p> [stab] [refine=...]``."""
        s = self.settings
        out = f"{s['method']} f{s['ss_f']} p{s['ss_p']}"
        out += " stab" if s.get("A_stability") else ""
        return out + (f" refine={s['refine']}" if s.get("refine", "auto") != "auto" else "")

    def as_dict(self) -> dict:
        m = self.model
        return {"label": self.label, "settings": dict(self.settings), "error": self.error,
                "same_as": self.same_as, "order": None if m is None else m.order,
                "spectral_radius": None if m is None else m.spectral_radius}


def candidate_settings(grid: Mapping, subsystem: str | None = None) -> list[dict]:
    """Identification settings of a candidate grid (config ``identification.loop_selection``).

    ``grid`` has ``methods``, ``horizons`` (``ss_f = ss_p``), ``a_stability`` (booleans) and
    optionally ``refine`` (``auto``/``none``, :func:`~ssamb.identification.identify`). The
    product is taken; ``A_stability=True`` is dropped for the PARSIM methods, which ignore it,
    and for the plant, which is open-loop unstable (a forced-stable plant model contradicts the
    physics: :data:`~ssamb.identification.selection.STABLE_SUBSYSTEMS`).
    """
    out = []
    for meth, h, stab, ref in itertools.product(grid["methods"], grid["horizons"], grid["a_stability"],
                                                grid.get("refine", ["auto"])):
        if stab and (meth not in _A_STABILITY_METHODS or (subsystem is not None and
                                                          subsystem not in STABLE_SUBSYSTEMS)):
            continue
        out.append({"method": str(meth), "ss_f": int(h), "ss_p": int(h), "A_stability": bool(stab),
                    "refine": str(ref)})
    return out


def _fingerprint(m: IdentifiedModel) -> str:
    h = hashlib.sha256()
    for a in (m.A, m.B, m.C, m.D):
        h.update(np.ascontiguousarray(a, float).tobytes())
    return h.hexdigest()


def identify_candidates(u, y, subsystem: str, order: int, settings: Sequence[Mapping], fs_hz: float,
                        input_names, output_names, *, input_directions=None,
                        known: Sequence[Candidate] = (), progress: bool = False,
                        affine: bool = True) -> list[Candidate]:
    """Identify one subsystem with each of ``settings``; a failure is a candidate with its error.

    ``known`` are candidates already identified (e.g. by the method comparison) and are reused
    when their settings match. Duplicated matrices are marked ``same_as`` the first label.
    ``affine`` is passed to :func:`~ssamb.identification.identify` (every candidate alike).
    """
    from tqdm import tqdm

    done = {_key(c.settings): c for c in known}
    out, seen = [], {}
    with identification_memo():  # settings of one horizon share SIPPY's projections (exact)
        for s in tqdm(settings, desc=f"candidates {subsystem}", disable=not progress, leave=False,
                      mininterval=5.0):
            c = done.get(_key(s))
            if c is None:
                try:
                    kw = {k: s[k] for k in ("ss_f", "ss_p", "A_stability", "refine")}
                    m = identify(u, y, order, s["method"], fs_hz, input_names, output_names,
                                 input_directions=input_directions, affine=affine, **kw)
                    c = Candidate(subsystem, dict(s), m)
                except DataError:
                    raise
                except Exception as exc:  # one failing setting must not hide the others
                    c = Candidate(subsystem, dict(s), None, f"{type(exc).__name__}: {exc}")
            if c.model is not None:
                fp = _fingerprint(c.model)
                c = Candidate(c.subsystem, c.settings, c.model, c.error, seen.get(fp))
                seen.setdefault(fp, c.label)
            out.append(c)
    return out


def _key(s: Mapping) -> tuple:
    return (s["method"], int(s["ss_f"]), int(s["ss_p"]), bool(s.get("A_stability", False)),
            s.get("refine", "auto"))


def score_loop(plant, amplifier, selfsensing, pid_x, pid_y, validation: Mapping,
               channels: Sequence[str] = AXES) -> dict:
    """Assemble one combination (:func:`ssamb.closed_loop.assemble_closed_loop`) and score it.

    Returns ``spectral_radius``, ``stable`` and, for a stable loop, ``fit_pct`` per channel of
    the replay of the validation record (:func:`ssamb.closed_loop.replay_fits`) and their mean
    ``mean_fit_pct``; an assembly error is returned as ``error``.
    """
    from ..closed_loop import assemble_closed_loop, replay_fits, stability

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cl = assemble_closed_loop(plant, amplifier, selfsensing, pid_x, pid_y)
    except ValueError as exc:
        return {"spectral_radius": None, "stable": False, "error": str(exc)}
    rep = stability(cl)
    out = {"spectral_radius": rep.spectral_radius, "stable": rep.stable}
    if rep.stable:
        fits = replay_fits(cl, validation, channels)
        out["fit_pct"] = fits
        out["mean_fit_pct"] = float(np.mean(list(fits.values())))
    return out


@dataclass(frozen=True)
class LoopSelection:
    """Result of :func:`select_loop`.

    Attributes
    ----------
    choice : dict or None
        subsystem -> the selected :class:`Candidate`; None when no combination is stable.
    table : list of dict
        Every combination evaluated: the candidate label per subsystem, ``spectral_radius``,
        ``stable``, ``fit_pct`` (validation, per channel) and ``mean_fit_pct``.
    rule : str
        The selection rule in words.
    candidates : dict
        subsystem -> list of :class:`Candidate` (including failed and duplicated ones).
    """

    choice: dict | None
    table: list
    rule: str
    candidates: dict = field(default_factory=dict)

    @property
    def best(self) -> dict | None:
        """The table row of the selected combination."""
        if self.choice is None:
            return None
        labels = {k: c.label for k, c in self.choice.items()}
        return next(r for r in self.table if all(r[k] == v for k, v in labels.items()))

    def as_dict(self) -> dict:
        return {"rule": self.rule, "selected": None if self.choice is None else
                {k: c.label for k, c in self.choice.items()}, "best": self.best, "table": self.table,
                "candidates": {k: [c.as_dict() for c in v] for k, v in self.candidates.items()}}


RULE = ("every combination of the candidates assembled (Fig. 3); among the stable loops "
        "(spectral radius < 1) the best mean validation fit of x_meas and y_meas (replay of "
        "the validation record from the operating point)")


def select_loop(candidates: Mapping[str, Sequence[Candidate]], pid_x, pid_y, validation: Mapping,
                channels: Sequence[str] = AXES, progress: bool = False) -> LoopSelection:
    """Assemble every combination of the candidates and select by the assembled loop.

    Parameters
    ----------
    candidates : mapping
        ``plant``, ``amplifier``, ``selfsensing`` -> candidates (failed ones and those
        ``same_as`` another are listed in the evidence but not assembled twice).
    pid_x, pid_y : control.StateSpace
        The discrete controllers.
    validation : mapping
        Columns of an independent closed-loop record (``t, r_x, r_y, inj_x, inj_y`` and the
        scored ``channels``); not the record of the Fig. 4 comparison.

    Returns
    -------
    LoopSelection
        ``choice`` is None if no combination is stable (the table then shows how close each
        came: the spectral radius of every combination).
    """
    from tqdm import tqdm

    subs = ("plant", "amplifier", "selfsensing")
    usable = {k: [c for c in candidates[k] if c.model is not None and c.same_as is None] for k in subs}
    combos = list(itertools.product(*(usable[k] for k in subs)))
    table = []
    for combo in tqdm(combos, desc="assembled loops", disable=not progress, leave=False, mininterval=5.0):
        row = {k: c.label for k, c in zip(subs, combo)}
        row.update(score_loop(*(c.model for c in combo), pid_x, pid_y, validation, channels))
        table.append(row)
    stable = [i for i, r in enumerate(table) if r["stable"] and np.isfinite(r["mean_fit_pct"])]
    choice = None
    if stable:
        i = max(stable, key=lambda j: table[j]["mean_fit_pct"])
        choice = dict(zip(subs, combos[i]))
    return LoopSelection(choice, table, RULE, {k: list(candidates[k]) for k in subs})


def position_path(amplifier: IdentifiedModel, pid, freqs_hz: Sequence[float], axis: str = "y") -> list[dict]:
    r"""How much of the controller's feedback a 4-input amplifier model carries (one axis).

    For the coil current :math:`i` of the axis' positive magnet, the command path
    :math:`G_u = i/u_{cmd}`, the position path :math:`G_p = i/\text{pos}` and the ratio
    :math:`G_p / (-G_u C)` (C the PID): 0 for a current-controlled amplifier that ignores the
    rotor, 1 when the model's position path equals the feedback the controller applies through
    the commands. In the paper's structure the assembled loop needs :math:`G_p` to stabilise the
    plant's unstable pole (module docstring), so stable combinations show large ratios.
    """
    ins = list(amplifier.input_names)
    j_u, j_p = ins.index(f"u_{axis}_cmd"), ins.index(f"{axis}_meas")
    i_o = list(amplifier.output_names).index(f"i_{axis}pos")
    A, B, C = amplifier.A, amplifier.B, amplifier.C
    out = []
    for f in freqs_hz:
        z = np.exp(2j * np.pi * f * amplifier.dt)
        g = C[i_o] @ np.linalg.solve(z * np.eye(amplifier.order) - A, B) + amplifier.D[i_o]
        c = complex(np.squeeze(pid(z)))
        out.append({"f_hz": float(f), "abs_Gu": float(abs(g[j_u])), "abs_Gp_a_per_m": float(abs(g[j_p])),
                    "Gp_over_minus_GuC": [float((g[j_p] / (-g[j_u] * c)).real), float((g[j_p] / (-g[j_u] * c)).imag)]})
    return out


def position_path_scan(plant, amplifier: IdentifiedModel, selfsensing, pid_x, pid_y,
                       factors: Sequence[float] = (0.0, 0.5, 1.0, 2.0, 5.0)) -> list[dict]:
    """Spectral radius of the assembled loop with the amplifier's position inputs scaled by each
    factor (0: a current-controlled amplifier that ignores the rotor; 1: the model)."""
    from ..closed_loop import assemble_closed_loop, stability

    cols = [list(amplifier.all_input_names).index(c) for c in amplifier.input_names if c.endswith("_meas")]
    out = []
    for k in factors:
        B, D = amplifier.B.copy(), amplifier.D.copy()
        B[:, cols] *= k
        D[:, cols] *= k
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cl = assemble_closed_loop(plant, amplifier.replace(B=B, D=D), selfsensing, pid_x, pid_y)
        out.append({"factor": float(k), "spectral_radius": stability(cl).spectral_radius})
    return out
