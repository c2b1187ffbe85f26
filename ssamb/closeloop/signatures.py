r"""Signatures: the evidence for each library effect of the device, before any fitting.

Each effect module of the device (:class:`ssamb.device.EffectModule`) states the signature it
leaves in the residual of the model and scores the evidence for it in the features of
:mod:`ssamb.closeloop.residual`. Scores share one currency, the part of the residual's
:math:`\chi^2` (squared residual over its noise floor) that the signature accounts for, so that
candidates are comparable and ranked. An effect is a candidate when its feature is significant
at ``alpha_evidence``, shared by the device's library (Bonferroni over the effects and, inside
each, over its axes or views).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from ..io import plain
from .residual import Features

__all__ = ["Evidence", "evidence_all", "rank", "claim_stat"]


@dataclass
class Evidence:
    """Evidence for one effect.

    Attributes
    ----------
    name : str
    score : float
        Explained :math:`\\chi^2` (0 when the signature is absent).
    log10_p : float
        log10 of the (Bonferroni-corrected) p-value of the signature's feature.
    significant : bool
    hints : dict
        What the features say about the parameters (axes, delays, gains, spin speed, ...).
    details : dict
        The numbers behind the score.
    signature : str
        The signature the effect predicts (one line, from its module).
    """

    name: str
    score: float
    log10_p: float
    significant: bool
    hints: dict = field(default_factory=dict)
    details: dict = field(default_factory=dict)
    signature: str = ""

    def to_json(self) -> dict:
        return {"score_chi2": self.score, "log10_p": self.log10_p, "significant": self.significant,
                "signature": self.signature, "hints": plain(self.hints), "details": plain(self.details)}


def evidence_all(ft: Features, settings, device) -> dict:
    """Evidence for every library effect of ``device`` (``settings.alpha_evidence`` is shared by
    the effects: Bonferroni; the signature thresholds are the settings' own)."""
    lib = device.effects
    names = device.library
    a = settings.alpha_evidence / max(len(names), 1)
    out = {}
    for name in names:
        d = lib[name].evidence(ft, a, settings)
        out[name] = Evidence(name, float(d["score"]), float(d["log10_p"]), bool(d["significant"]),
                             dict(d.get("hints", {})), dict(d.get("details", {})), lib[name].SIGNATURE)
    return out


def rank(ev: dict) -> list[str]:
    """Effects with significant evidence, strongest first."""
    return [e.name for e in sorted(ev.values(), key=lambda e: -e.score) if e.significant]


def claim_stat(device, name: str, ft: Features, hints: dict, df_hz: float, settings) -> float:
    """The explained chi^2 of an effect's own feature in ``ft`` (used before and after its fit)."""
    return float(device.effects[name].claim(ft, hints, df_hz, settings))
