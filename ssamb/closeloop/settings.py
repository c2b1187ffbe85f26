"""Settings of the close-the-loop analysis (the ``closeloop`` section of ``config.yaml``).

Every field has a default, so a config without a ``closeloop`` section (or a user's own physics
config) still works; :func:`settings_from_config` overrides the defaults with the section's
keys (``datasets`` and ``default_dataset`` are workflow keys and are ignored here).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping

__all__ = ["Settings", "settings_from_config", "canonical_order"]


@dataclass(frozen=True)
class Settings:
    """Analysis settings.

    Attributes
    ----------
    fit_fraction : float
        Fraction of the analysed record (after ``discard_s``) used for fitting; the rest is the
        held-out part on which every reported error is computed.
    discard_s : float
        Start-up time discarded before the analysis (the replay starts from the nominal
        equilibrium, a rig record does not); rounded up to whole excitation periods.
    min_fit_s, min_holdout_s : float
        Shortest fitting and held-out parts accepted ("too short to split" otherwise).
    alpha_evidence : float
        Family-wise significance level of a signature feature (Bonferroni inside each feature
        family: offsets, lines, excited-line residuals, ...).
    alpha_accept : float
        Significance level of the held-out improvement test of a fitted effect.
    alpha_noise : float
        Family-wise level of the "residual consistent with noise" tests (offsets,
        lines, residual coherent with the excitation).
    min_explained : float
        Smallest fraction of the residual excess (power above the noise floor, held out) that an
        effect must explain to be declared (practical significance).
    max_effects : int
        Most effects added by the greedy search.
    candidates_per_round : int
        Candidates fitted per greedy round (the best-ranked ones with significant evidence).
    sufficient_share : float
        A candidate that passes and explains at least this share of the held-out residual excess
        ends its round's fits of single effects: the candidates ranked after it were ranked
        against a residual it dominates, and are ranked again against the base with it in the
        next round (the aliases of the chosen effect are still fitted beside it). 1 or more
        fits every ranked candidate.
    line_search_max_hz : float
        Upper frequency of the search for lines the excitation does not contain.
    ripple_min_hz : float
        Lower frequency of the band in which current-ripple distortion is looked for.
    floor_position_m, floor_current_a : float
        Smallest noise level assumed for a channel (a channel logged without noise, like the
        digital controller outputs, would otherwise get infinite weight).
    floor_relative : float
        Smallest noise level relative to a channel's signal rms (model reproducibility: a
        deterministic residual below it is not evidence; data stored in single precision carry
        ~1e-7, the simulator's own changes ~1e-9).
    replay_seeds : int
        Replays (distinct converter-noise seeds) averaged into a prediction: the model's expected
        response, its own noise divided by this number (a replay is one realisation of the loop's
        noise, as the rig's record is another).
    calibration : dict
        Calibratable nominal parameters: dotted config key -> prior tolerance (standard
        deviation; relative to the nominal value, absolute in the key's unit when the nominal
        value is 0). Empty: no calibration; None: the device's priors. A set: in the canonical
        order (:func:`canonical_order`), whatever order the config lists them in, so the
        estimate does not depend on it.
    session : tuple of str
        Calibrated parameters (keys of ``calibration``) that may change between recordings of one
        rig, like a sensor's alignment after the rig is touched. Over several recordings
        (:mod:`ssamb.closeloop.recordings`) they are neither combined nor required to agree; a
        held-out recording's are calibrated on its own fitting part, with everything else fixed,
        and its errors are taken on the rest. In the order of ``calibration``.
    calibration_restarts : int
        Fits of each calibration (a recording's, the joint one, a held-out recording's session
        parameters), each with its own design, of which the one whose replays drop the body
        least and fit the fitting data best is kept (:func:`ssamb.closeloop.estimate.best_fit`):
        where a fit's end depends on its path, the best of several is less so.
    noise_at_calibration : bool
        Read the noise again about the calibrated model before the effect search
        (:meth:`ssamb.closeloop.comparison.Comparison.calibrate_noise`). A part without a periodic
        excitation reads the data's noise off the residual of the data from a model's replays;
        read about the calibration's start only, whatever that start misfits -- its parameters'
        errors, and the very effect the search is after -- counts as noise in every later test,
        and a held-out improvement it hides is not seen. Not where a replay of the calibrated model
        drops the body (no model of the rig's noise). Off by default: a periodic excitation reads
        the data's noise off the data alone.
    nested_refit : bool
        A candidate that passes against the base must also improve the held-out part
        significantly over the model nested in it: the base's parameters refitted with the
        candidate's freedom, the effect pinned at zero
        (:func:`ssamb.closeloop.search.parameters_only`). Where the calibration ends short of the
        rig, every candidate fitted with the parameters free improves the held-out part, whatever
        its size; the nested comparison credits the effect only with what the parameters' refit
        alone does not explain. Off by default: a periodic excitation's calibration ends at its
        optimum and the refit adds nothing there.
    rivals : bool
        Once a candidate passes in a round, fit every other library effect not yet tried in it,
        and report the passing ones the held-out part cannot tell from the chosen one as its rivals
        (:func:`ssamb.closeloop.search.champion`): effects that explain the data alike are both
        named. Off by default (each round then fits its ranked candidates only).
    calibration_step_rel : float
        Largest finite-difference step of a relative parameter (a wider tolerance reaches where
        the response is no longer linear).
    identifiable_ratio : float
        A parameter counts as identified when the data shrink its tolerance to at most this
        fraction (posterior standard deviation over the prior's).
    conflict_z : float
        A calibrated parameter further than this many tolerances from nominal conflicts with its
        stated tolerance; the effect search starts with it at its nominal value.
    claim_residual : float
        An accepted effect must leave at most this fraction of its own signature's statistic
        (or less than the evidence threshold, the two-degree one and its own evidence test's) in
        the residual: it must act on what it claims (an unbalance fitted to one axis of a
        two-axis line fails).
    candidate_iterations : int
        Gauss-Newton iterations of a candidate's fit (it starts from the calibrated model and the
        evidence's hints, close to its optimum).
    candidate_start : str
        Where a candidate's fit starts: ``prior`` (its base's unidentified parameters at their
        prior mean, so that an effect may take what they had absorbed); ``better``: that start
        or the base as it is, whichever costs less beyond the cost's noise
        (:func:`ssamb.closeloop.fit.better_base_start`); ``rescue``: the prior start, and a fit
        that stops short above the cost of its base as it is (no effect) is fitted again from
        there (:func:`ssamb.closeloop.fit._rescued`; the default). A fit of a few iterations ends near its
        start, and a start far worse than the base it extends can leave the candidate worse
        than no effect at all.
    joint_iterations : int
        Most Gauss-Newton iterations of the final joint refit (it starts from the fitted values
        and stops once converged; not capped by the estimator's ``max_iter``).
    joint_restarts : int
        Where the joint refit ends far above the noise floor, the number of other basins of the
        accepted effects' coarse grids it is refitted from, per effect parameter
        (:func:`ssamb.closeloop.search.other_basins`); 0: none.
    average_alternatives : bool
        Report the calibrated parameters' standard errors over the final model and the candidates
        of the search's last round, weighted by their BIC (:func:`ssamb.closeloop.search.averaged_errors`):
        an effect the held-out test could not confirm but the data do not exclude widens the
        errors of the parameters it moves. False: the final model's errors alone.
    estimate : dict
        Settings of the estimator (:class:`ssamb.closeloop.estimate.EstimateSettings`).
    whirl_phase_min_deg : float
        Unbalance signature: the y line lags the x line by between this and 180 minus this
        degrees (forward whirl; the x probe loop and the y self-sensing loop differ, hence the
        width).
    whirl_ratio_max : float
        Unbalance signature: the y/x amplitude ratio of the line lies within ``1/r .. r``.
    line_isolation : float
        A line on an excited frequency (an unbalance spinning there) stands out when its
        chi-square is this many times the median of the other excited lines, in both axes.
    ratio_min_snr : float
        Excited lines whose measured sensor or current response is below this amplitude
        signal-to-noise ratio are left out of the sensor-path ratio.
    ratio_path_min_lines, ratio_path_se_factor : int, float
        The y sensor path is read as the self-sensing estimate over the evaluation probe when
        it has this many lines and its delay's standard error is within this factor of the
        path over the coil current (else the latter: current pulses barely move the rotor).
    deadtime_ratio_max : float
        Dead-time signature: the common-mode shifts of the two axes agree within this factor.
    above_noise : float
        A view stands clearly above the noise when its chi-square is this many times its entries.
    excess_share : str
        How the share of the held-out excess a candidate explains is taken over the groups clearly
        above the noise (:func:`ssamb.closeloop.fit.excess_share`): ``"sum"``, the excess removed
        over the excess (a group whose excess is near zero cannot swing it), or ``"mean"``, the
        mean of the groups' own shares (every group above the noise has one vote: a candidate
        must explain more than the group with the most excess).
    worse_sigma : float
        A candidate makes a view worse when its chi-square grows by more than this many standard
        deviations of the difference of two noisy predictions' chi-square.
    contact_fraction : float
        The measured rotor touched the backup bearing when its radial position reached this
        fraction of the clearance (a candidate whose model touches is then not implausible).
    device_line_relative : float
        The model's reproducibility at the device's own lines, relative to a line's amplitude
        (a views compared there only, :attr:`ssamb.device.FeatureSpec.device_line_views`): a
        noise-free logged output's deterministic lines carry structure no calibrated parameter
        reproduces exactly (the rig's own clamped DCM calibration), far above their in-loop noise.
    """

    fit_fraction: float = 0.7
    discard_s: float = 0.1
    min_fit_s: float = 0.1
    min_holdout_s: float = 0.05
    alpha_evidence: float = 1e-3
    alpha_accept: float = 1e-3
    alpha_noise: float = 1e-3
    min_explained: float = 0.2
    max_effects: int = 3
    candidates_per_round: int = 3
    sufficient_share: float = 0.9
    line_search_max_hz: float = 2000.0
    ripple_min_hz: float = 2000.0
    floor_position_m: float = 1e-10
    floor_current_a: float = 1e-6
    floor_relative: float = 1e-5
    replay_seeds: int = 8
    calibration: dict | None = None
    session: tuple = ()
    calibration_restarts: int = 1
    noise_at_calibration: bool = False
    nested_refit: bool = False
    rivals: bool = False
    calibration_step_rel: float = 0.05
    identifiable_ratio: float = 1.0 / 3.0
    conflict_z: float = 3.0
    claim_residual: float = 0.5
    candidate_iterations: int = 4
    candidate_start: str = "rescue"
    joint_iterations: int = 12
    joint_restarts: int = 1
    average_alternatives: bool = True
    estimate: dict = dataclasses.field(default_factory=dict)
    whirl_phase_min_deg: float = 10.0
    whirl_ratio_max: float = 5.0
    line_isolation: float = 100.0
    ratio_min_snr: float = 10.0
    ratio_path_min_lines: int = 10
    ratio_path_se_factor: float = 3.0
    deadtime_ratio_max: float = 3.0
    above_noise: float = 2.0
    excess_share: str = "sum"
    worse_sigma: float = 3.0
    contact_fraction: float = 0.95
    device_line_relative: float = 0.02


_WORKFLOW_KEYS = ("datasets", "default_dataset", "rigs")


def canonical_order(calibration: Mapping, device=None) -> dict:
    """``calibration`` (dotted key -> tolerance) in the canonical order of its keys: the device's
    own order of its calibratable parameters (:meth:`ssamb.device.Device.priors` of its default
    configuration), then any other keys sorted.

    The parameters are a set, but the estimator's design gives each position its own
    perturbation pattern (:func:`ssamb.closeloop.estimate._pairs`), so their order is one of the
    arbitrary choices a result may depend on; fixed by the device, it is the same whatever order
    a configuration file, or a workflow that sorts every mapping, lists them in.
    """
    own: list = []
    if device is not None:
        try:
            own = list(device.priors(device.default_config()))
        except NotImplementedError:          # a device without a default configuration of its own
            own = []
    rank = {k: i for i, k in enumerate(own)}
    return dict(sorted(dict(calibration).items(), key=lambda kv: (rank.get(kv[0], len(rank)), kv[0])))


def _err(msg: str):
    from ..config import ConfigError

    return ConfigError(msg)


def settings_from_config(cfg: Mapping | None, device=None) -> Settings:
    """Settings from ``cfg['closeloop']`` (missing keys keep their defaults; without a
    ``calibration`` the device's priors, :meth:`ssamb.device.Device.priors`, are calibrated).

    Raises
    ------
    ssamb.config.ConfigError
        An unknown key (named) or a value out of range.
    """
    section = dict((cfg or {}).get("closeloop") or {})
    known = {f.name for f in dataclasses.fields(Settings)}
    kw = {}
    for k, v in section.items():
        if k in _WORKFLOW_KEYS:
            continue
        if k not in known:
            raise _err(f"config key 'closeloop.{k}': unknown (known: {', '.join(sorted(known))})")
        kw[k] = v
    ds = section.get("datasets") or {}
    if "default_dataset" in section and section["default_dataset"] not in ds:
        raise _err(f"config key 'closeloop.default_dataset': '{section['default_dataset']}' is not in "
                         f"closeloop.datasets (known: {', '.join(ds) or 'none'})")
    if kw.get("calibration") is None and device is not None:
        kw["calibration"] = dict(device.priors(cfg or {}))
    # a set of parameters, not a sequence: the estimator sees them in one canonical order,
    # whatever order a file or a canonicalised (sorted) workflow config lists them in
    if kw.get("calibration") is not None:
        kw["calibration"] = canonical_order(kw["calibration"], device)
    if "session" in kw:
        kw["session"] = tuple(k for k in (kw.get("calibration") or {}) if k in set(kw["session"] or ())) + \
            tuple(sorted(set(kw["session"] or ()) - set(kw.get("calibration") or {})))
    s = Settings(**kw)
    unknown = [k for k in s.session if k not in (s.calibration or {})]
    if unknown:
        raise _err(f"config key 'closeloop.session': {', '.join(unknown)} not in closeloop.calibration")
    if not 0.1 <= s.fit_fraction <= 0.95:
        raise _err(f"config key 'closeloop.fit_fraction': must be in [0.1, 0.95] (got {s.fit_fraction})")
    for name in ("alpha_evidence", "alpha_accept", "alpha_noise"):
        if not 0 < getattr(s, name) < 0.5:
            raise _err(f"config key 'closeloop.{name}': must be in (0, 0.5)")
    if int(s.replay_seeds) < 1:
        raise _err("config key 'closeloop.replay_seeds': must be >= 1")
    if int(s.calibration_restarts) < 1:
        raise _err("config key 'closeloop.calibration_restarts': must be >= 1")
    from .estimate import EstimateSettings

    known_est = {f.name for f in dataclasses.fields(EstimateSettings)}
    for k in s.estimate:
        if k not in known_est:
            raise _err(f"config key 'closeloop.estimate.{k}': unknown (known: {', '.join(sorted(known_est))})")
    return s
