r"""Maximum a posteriori estimation with a noisy simulator: Gauss-Newton on a regression surrogate.

The quantity fitted is a whitened feature residual :math:`r(\theta) \in \mathbb R^N` (model
minus data, unit noise covariance: :class:`ssamb.closeloop.features.Whitener`). A replay is a
noisy function of :math:`\theta`: every evaluation carries a fresh realisation of the loop's
pseudo-noise, :math:`r(\theta, s) = \bar r(\theta) + \varepsilon_s`, with
:math:`E\,\varepsilon\varepsilon^T = \rho I` (:math:`\rho < 1`: the model's share of the noise).
Finite differences of single evaluations, or a local optimiser that compares costs of
single evaluations, chase :math:`\varepsilon` (an optimiser that keeps the best of many
draws finds a cost several standard deviations below its expectation, and parameters many
standard errors off). This module therefore never compares single evaluations:

1. **Design.** At the centre :math:`\theta_k`: ``centre_runs`` evaluations with distinct seeds,
   and mirror pairs :math:`\theta_k \pm h \odot z_j` sharing one seed (common random numbers
   cancel the part of the noise that a parameter change does not re-randomise), the signs
   :math:`z_j` the rows of an orthogonal array over all parameters at once (:func:`_pairs`).
2. **Surrogate.** The linear model :math:`r(\theta) \approx a + B(\theta - \theta_k)`: the
   anchor :math:`a` is the mean of the centre runs (no curvature bias from the pairs), the
   Jacobian :math:`B` the least-squares fit to every evaluation so far within ``pool_radius``
   steps of the centre in every coordinate (:func:`_surrogate`). :math:`\rho` is the pooled
   variance of the centre runs.
3. **Information.** The noise of :math:`\hat B` inflates :math:`\hat B^T\hat B` by
   :math:`N\rho\,(X^TX)^{-1}` (errors in variables): a parameter the features do not depend on
   gets a column of pure noise, and a valley along which two parameters trade off (rotor mass
   and coil turns) a curvature it does not have. The correction is subtracted and the result
   made positive semi-definite (:func:`_information`).
4. **Step.** With the prior :math:`\theta \sim N(\theta_0, \mathrm{diag}\,\sigma_p^2)`
   (:math:`\sigma_p = \infty` for parameters without one) the Gauss-Newton step minimises
   :math:`\|a + B d\|^2 + \|(\theta_k + d - \theta_0)/\sigma_p\|^2`, restricted to the directions
   the data determine: the Jacobian's signal above its noise (``min_snr``, raised where the
   replays' noise moves whole views together: :func:`_information`) and the information
   above ``min_information`` (along the others the estimate stays where the prior holds it,
   instead of following the surrogate's noise); shortened to the bounds and a trust region of
   ``max_step`` steps :math:`h`, which doubles after an accepted step that lowered the cost by
   at least a quarter of what the surrogate promised (up to ``max_trust``) and becomes
   ``reject_shrink`` of the step tried after a rejected or infeasible one.
5. **Accept** the step only if the anchor at the new centre is not worse than the old one by
   more than two standard deviations of the difference of two noisy anchors at that cost
   (:func:`_margin`); a rejected trial's runs stay in the pool and inform :math:`B` along the step.
   A step where most replays are **infeasible** -- the body hits a stop the data do not hit, or
   the parameters leave the device's physical domain (the residual is NaN) -- or more of them
   than at the current centre, is rejected without a cost (one with fewer is accepted without
   one); infeasible runs never enter the surrogate, and a design with many of them is redone
   with half the steps (a step that drops the ball is no finite difference of the cost).
6. **Replicate** the pairs at the same centre when the step is at the noise level but some
   direction looks informative while its Jacobian is still noise (a weakly determined valley
   between two parameters needs them). A direction a few entries determine (a DC offset)
   is found row by row (:func:`_concentrated`).
7. **Stop** when the step is at the noise level, :math:`\sqrt{d^T H d / p} <` ``tol`` with
   :math:`H = \hat{\mathcal I} + \Lambda` the posterior precision (the natural metric: a step
   along a weakly determined valley is measured against the valley's own uncertainty), or after
   ``max_iter`` iterations -- unless the cost is still far above the noise floor (the truth-free
   check, ``short_alpha``): then up to ``short_iter`` more, a stall halves the steps, and a rest
   along the determined directions widens the steps of the others (``max_refresh``); a fit that
   ends unconverged so far above the floor has *stopped short* and says so. The estimate is
   :math:`\hat\theta = \theta_k + d`; its covariance the
   sandwich of :func:`_sandwich`: the data on the directions the estimate moved along, with the
   noise the final centre's replicates show (the rig is one more replay), the prior elsewhere,
   and what the prior's spread there does to the rest. When the iterations ran out first the
   estimate is the last centre, and the last step :math:`d d^T` joins its covariance.
8. **Probe** a parameter that may be probed (an effect's size) and that no determined direction
   holds: its step grows and the pairs are redone at the same centre (``probe_growth``).

:func:`map_fit` knows nothing of the device: it evaluates a callable ``(theta, seed) -> r``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

__all__ = ["Problem", "MapFit", "map_fit", "best_fit", "common_seeds_fit", "drops_and_cost", "EstimateSettings"]


@dataclass(frozen=True)
class EstimateSettings:
    """Settings of :func:`map_fit` (the ``closeloop.estimate`` block of the config).

    Attributes
    ----------
    centre_runs : int
        Evaluations at each centre (distinct seeds): their mean is the surrogate's anchor and
        their spread the model noise.
    pair_runs : int
        Replicates (distinct seeds) of the design's mirror pairs.
    design : str
        ``signs`` (all parameters perturbed at once with random signs) or ``axes`` (one at a
        time): :func:`_pairs`.
    max_iter : int
        Gauss-Newton iterations.
    tol : float
        Stop when the step's norm in the posterior metric, per parameter, is below ``tol``.
    pool_radius : float
        Earlier evaluations within this many steps :math:`h` of the centre (every coordinate)
        join the surrogate's regression.
    max_step : float
        Trust region per iteration, in finite-difference steps :math:`h`.
    min_information : float
        Directions whose data information, in units of the scale (prior standard deviation, or
        step without a prior), is below this are not stepped along: there the data are not
        informative and the noise of the surrogate would move the estimate at random (8: the
        data shrink the prior uncertainty at least 3 times).
    max_replicates : int
        Replicates of the pairs at one centre for directions that look informative while their
        Jacobian is still noise (step 6). Each halves the Jacobian's noise variance; a direction
        still below ``min_snr`` after two is weak enough to stay at its prior (without the cap a
        calibration can replicate one direction again and again, 160 replays for five rounds,
        without its estimate moving).
    min_trust : float
        The trust region below which an estimate whose surrogate still asks for a step larger
        than ``tol`` is stalled (no step it tried improved the fit): the fit stops, not converged.
    probe_growth, max_probes : float, int
        A parameter that may be probed (:attr:`Problem.probe`: an effect's size) and lies in no
        determined direction has its finite-difference step multiplied by ``probe_growth`` and the
        pairs redone at the same centre, at most ``max_probes`` times (step 8). The noise of the
        Jacobian spreads over all N entries of the residual, its signal may sit in a few (a static
        load moves the DC entries of the currents): the signal-to-noise ratio of the column grows
        with the square of the step, and an effect linear in its size loses nothing by a wide one.
    reject_shrink : float
        After a rejected or infeasible step the trust region becomes this fraction of the step
        just tried (not of the region: a step the bounds or the surrogate had already shortened
        would otherwise be tried again nearly unchanged). A step whose replays hit a stop the data
        do not hit, or leave the physical domain, fails in a region the linear surrogate does not
        describe: there the cost says nothing about the direction, only that the step was too long.
    short_alpha, short_iter : float, int
        The truth-free check of a fit that has not converged: its cost :math:`\\|a\\|^2` above the
        floor the noise gives, :math:`f` (the data's noise per whitened entry, at least the unit,
        and the model noise of the anchor, the mean of :math:`m` centre runs: :func:`noise_floor`),
        beyond the upper ``short_alpha`` quantile of :math:`(f/\\nu)\\,\\chi^2_\\nu`, :math:`\\nu` the
        effective degrees of freedom of a noise that moves whole views together (:func:`_far_above`). While it holds,
        the fit goes on for up to ``short_iter`` iterations beyond ``max_iter`` (and may refresh or
        widen its steps, ``max_refresh``; ``short_iter`` 0: neither, as for a candidate's fit, a
        screen on a base that misfits by design); a fit that ends unconverged with it still
        holding has *stopped short* (:attr:`MapFit.stopped_short`), and says so.
    moving_step, moving_iter : float, int
        A fit whose last step asked for more than ``moving_step`` posterior standard deviations
        per parameter, after a step that removed more than half of its cost's excess over the
        floor, is still on its way: it goes on for up to ``moving_iter`` iterations beyond
        its limit while that holds (0: never, the default). A candidate's fit, limited to a few
        iterations as a screen, is otherwise judged where it happens to stop, far from its own
        optimum: the search gives it ``closeloop.candidate_iterations`` more.
    progress_window : int
        The fit stops when the cost at its centre has not fallen by more than the anchors' noise
        (:func:`_margin`, two standard deviations of the difference of two anchors at that cost)
        over the last ``progress_window`` steps it tried (0: never): the surrogate's steps no
        longer lower the cost, so further iterations only move the centre about within the
        cost's noise (a model that lacks an effect the data show keeps proposing steps its
        linear surrogate promises and the replays do not deliver). The fit has not converged
        (its last step joins its covariance) but rests at a point no step of its surrogate
        improves by more than the noise: a local optimum within the cost's resolution. Off by
        default: the anchors' noise is that of single replays, and a mean of replays still tells
        points apart that it does not -- with a window of 3 the randomized suite's final models
        were beaten by the truth held out where they were not without it (the validation page).
    short_progress_window : int
        The :func:`_no_progress` test over this many steps (0: never) in the iterations a fit is
        given beyond ``max_iter`` only (``short_iter`` far above the floor, ``moving_iter`` while
        still on its way): those iterations exist for a fit still lowering its cost, and one
        whose last steps no longer lower it by more than the anchors' noise is at rest beside a
        misfit the parameters cannot remove (an effect the model lacks), where more iterations
        only move its centre about. The first ``max_iter`` iterations are untouched. The search
        uses it in the calibration and the candidates' fits, not in the final joint refit, which
        makes the reported model.
    design_seed : int
        Which orthogonal array the design draws (:func:`_pairs`): 0, the first ``p`` columns of
        the Hadamard matrix in the parameters' order; another value, columns, signs and rows drawn
        with it. An arbitrary choice, like the order of the parameters was: an estimate that moves
        with it has not converged, and its spread over a few values is the path's share of the
        uncertainty (``bench/maglev_spread.py``).
    common_seeds : int
        0 (default): none. Otherwise :func:`map_fit` (and :func:`best_fit`, with one fit: no design
        to vary) solves the *sample-average* problem instead (:func:`common_seeds_fit`), without
        the surrogate:
        the mean residual of ``common_seeds`` replays with the same seeds at every point,

        .. math:: \\bar r_S(\\theta) = \\frac{1}{S}\\sum_{s=1}^{S} r(\\theta, s),

        is a deterministic function of :math:`\\theta`, smooth where a seeded replay is (the ball's
        additive quantisers), whose minimiser beside the prior's rows is found by a standard
        trust-region least-squares solver with fine finite differences. It is the noise-free
        problem up to one realisation of the replays' noise, :math:`\\bar\\varepsilon_S`, shared by
        every point: comparing two points never compares two realisations. Where the cost lies in a
        narrow curved valley (the force balance: a few per cent of one parameter moves the cost by
        orders of magnitude) the surrogate's finite differences over one tolerance cannot follow it.
        A device whose replays are not smooth in the parameters (rounding) must keep 0.
    common_seeds_evaluations : int
        The most residual evaluations (each ``common_seeds`` replays) of that solve.
    max_refresh : int
        A fit that stalls (trust region below ``min_trust``) while its cost is far above the floor
        halves its finite-difference steps and redoes the design at the same centre, at most this
        many times: the surrogate's slope over the old steps did not describe the cost near the
        centre (a response that is not linear over a step). Also the number of times the steps
        are halved when more than half of a design's replays are infeasible, and the number
        of times a fit at rest along its determined directions while its cost is far above the
        floor widens the steps of the parameters no determined direction holds (``probe_growth``)
        and redoes the design: the data may determine them at a wider step.
    """

    centre_runs: int = 4
    pair_runs: int = 1
    design: str = "signs"
    max_iter: int = 8
    tol: float = 1.0
    pool_radius: float = 1.0
    max_step: float = 2.0
    min_information: float = 8.0
    min_snr: float = 4.0
    max_trust: float = 16.0
    max_replicates: int = 2
    probe_growth: float = 4.0
    max_probes: int = 2
    min_trust: float = 1.0 / 16.0
    reject_shrink: float = 0.25
    short_alpha: float = 1e-3
    short_iter: int = 8
    max_refresh: int = 2
    design_seed: int = 0
    progress_window: int = 0
    short_progress_window: int = 0
    moving_step: float = 4.0
    moving_iter: int = 0
    common_seeds: int = 0
    common_seeds_evaluations: int = 200


@dataclass
class Problem:
    """A parameter estimation problem.

    Attributes
    ----------
    names : tuple of str
    theta0 : numpy.ndarray
        Prior mean (and start point).
    prior_sd : numpy.ndarray
        Prior standard deviations (``inf``: no prior).
    step : numpy.ndarray
        Finite-difference half-steps :math:`h`.
    lower, upper : numpy.ndarray
        Bounds.
    evaluate : callable
        ``(theta, seed) -> r``, the whitened residual (model minus data); not finite (NaN) where
        ``theta`` is infeasible: its replay hit a stop the data do not hit, or left the physical
        domain. An infeasible evaluation is never part of the surrogate, and a step to where one
        is infeasible is rejected.
    start : numpy.ndarray, optional
        Start point (default ``theta0``).
    seed0 : int
        First seed of the design (seeds are ``seed0 + 1000 k + i``).
    groups : list of index arrays, optional
        Entries of the residual that share a noise level (the views): the replicates' excess
        variance is pooled per group for the sandwich covariance (:func:`_sandwich`).
    evaluate_many : callable, optional
        ``[(theta, seed), ...] -> [r, ...]``: a batch of independent evaluations (a design's
        runs), e.g. on several processes; default ``evaluate`` in turn.
    probe : numpy.ndarray of bool, optional
        Parameters whose step may grow when no determined direction holds them
        (:class:`EstimateSettings` ``probe_growth``); default: those without a prior.
    fallback : numpy.ndarray, optional
        Where to start when the start is infeasible (most of its replays hit a stop): a point
        known to be feasible, e.g. the calibrated model a candidate is added to (default
        ``theta0``, when the start is elsewhere).
    """

    names: tuple
    theta0: np.ndarray
    prior_sd: np.ndarray
    step: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    evaluate: Callable[[np.ndarray, int], np.ndarray]
    start: np.ndarray | None = None
    seed0: int = 1
    groups: list | None = None
    evaluate_many: Callable | None = None
    probe: np.ndarray | None = None
    fallback: np.ndarray | None = None

    def batch(self, tasks: list) -> list:
        """Evaluate ``[(theta, seed), ...]`` (:attr:`evaluate_many` when given)."""
        if self.evaluate_many is not None and len(tasks) > 1:
            return [np.asarray(r, float) for r in self.evaluate_many(tasks)]
        return [np.asarray(self.evaluate(t, sd), float) for t, sd in tasks]


@dataclass
class MapFit:
    """Result of :func:`map_fit`.

    Attributes
    ----------
    theta, cov : numpy.ndarray
        Estimate and its covariance (data, model noise and prior).
    cov_misfit : numpy.ndarray
        The covariance with each view's noise raised to the residual's own scatter where the
        model misfits (:func:`_sandwich`): the one to report with the final model (a search's
        intermediate fits keep ``cov``: a model still missing an effect misfits by design).
    B : numpy.ndarray
        Surrogate Jacobian at the estimate's centre (N x p, whitened residual per unit
        parameter); its columns are the sensitivities the identifiability analysis reads.
    info : numpy.ndarray
        Data information :math:`\\hat B^T\\hat B` less its noise (p x p, without the prior), in all
        directions.
    chi2 : float
        :math:`\\|a\\|^2` at the last centre (mean of the centre runs).
    n : int
        Length of the residual.
    rho : float
        Model noise variance per whitened entry (single evaluation).
    evaluations, iterations : int
    converged : bool
    history : list of dict
        Per iteration: centre, step, chi2, rho.
    centre_runs : list
        The residuals of the last centre's runs.
    floor, floor_dof : float
        The cost the noise alone gives at the last centre and its effective degrees of freedom
        (:func:`noise_floor`: :math:`N(1 + \\rho/m)` and :math:`N` where the replays are quieter
        than the whitening's unit and their noise is independent between entries; 0: :math:`N`).
    stopped_short : bool
        The fit ended without converging (iterations out, or stalled) while its cost was still
        far above :attr:`floor` (``short_alpha`` of :class:`EstimateSettings`): a better model may
        lie beyond where it stopped.
    infeasible : int
        Replays whose body hit a stop the data do not show, or whose parameters left the physical
        domain (:attr:`Problem.evaluate` returned a non-finite residual): never part of a fit.
    """

    theta: np.ndarray
    cov: np.ndarray
    cov_misfit: np.ndarray
    B: np.ndarray
    info: np.ndarray
    chi2: float
    n: int
    rho: float
    evaluations: int
    iterations: int
    converged: bool
    history: list = field(default_factory=list)
    centre_runs: list = field(default_factory=list)
    floor: float = 0.0
    floor_dof: float = 0.0
    stopped_short: bool = False
    infeasible: int = 0

    @property
    def floor_ratio(self) -> float:
        """:attr:`chi2` over the noise floor :attr:`floor` (1 at a model the data cannot reject)."""
        return self.chi2 / self.floor if self.floor > 0 else float("nan")

    @property
    def se(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    @property
    def se_misfit(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov_misfit), 0.0))


def _prior_precision(sd: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(sd), 1.0 / np.where(np.isfinite(sd), sd, 1.0) ** 2, 0.0)


def _inverse(H: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive semi-definite matrix in the coordinates ``theta / scale``,
    eigenvalues floored at 1e-12 of the largest and at 1e-12 (a direction without information
    gets a huge, not an infinite, variance)."""
    S = np.outer(scale, scale)
    w, V = np.linalg.eigh(0.5 * (H + H.T) * S)
    w = np.maximum(w, max(1e-12 * float(w.max()), 1e-12))
    return ((V / w) @ V.T) * S


def _surrogate(runs: list, centre: np.ndarray, step: np.ndarray, radius: float, rho: float):
    r"""Least-squares ``r ~ a + B (theta - centre)`` over the runs within ``radius`` steps of
    the centre (every coordinate).

    Returns ``(B, noise)``: the Jacobian and the covariance its noise adds to :math:`B^TB`,
    :math:`N\rho\,(X^TX)^{-1}_{\theta\theta}` (:math:`\rho` the variance of a single
    evaluation per entry, from the centre replicates -- not the regression's residual, which
    also holds the surrogate's lack of fit over the pooled region; :math:`N` the length of the
    residual).
    """
    near = [(t, r) for t, r in runs if np.all(np.abs(t - centre) <= radius * step * (1 + 1e-9))]
    X = np.array([np.concatenate([[1.0], t - centre]) for t, _ in near])
    Y = np.array([r for _, r in near])
    coef, *_ = np.linalg.lstsq(X, Y, rcond=None)
    return coef[1:].T, Y.shape[1] * rho * np.linalg.pinv(X.T @ X)[1:, 1:]


def _information(B: np.ndarray, noise: np.ndarray, scale: np.ndarray, s: "EstimateSettings", prior_sd: np.ndarray,
                 entries: float = 0.0):
    r"""Data information corrected for the Jacobian's noise, and the directions worth stepping along.

    :math:`\hat{\mathcal I} = \hat B^T\hat B - N s^2 (X^TX)^{-1}` (errors in variables: the
    noise of :math:`\hat B` would otherwise look like information, most of all along weakly
    determined valleys), made positive semi-definite, in parameter units.

    The directions: the generalised eigenvectors :math:`u` of
    :math:`(\hat B^T\hat B,\ N s^2 (X^TX)^{-1})` in scaled coordinates (``scale``: prior standard
    deviations, or steps), normalised to unit noise. Along :math:`u` the Jacobian's signal-to-noise
    ratio is the eigenvalue :math:`\lambda` and the corrected information per scale unit is
    :math:`(\lambda - 1)/\|u\|^2`; a direction is kept when :math:`\lambda \ge` ``min_snr`` (else the
    gradient along it is the surrogate's noise) and its information is at least
    ``min_information`` (else the data are not informative there) -- or, for a direction mostly
    along parameters without a prior (an effect's), at least one step's worth (a step :math:`h`
    moves the features by a standard deviation).

    The noise's eigenvalues scatter about 1: for a noise worth :math:`\nu` independent entries
    (``entries``, :func:`effective_entries`; :math:`N` when 0) the largest of :math:`p` comes near
    the Marchenko-Pastur edge :math:`(1 + \sqrt{p/\nu})^2`, which a noise that moves whole views
    together (few effective entries) takes above ``min_snr``: pure noise would pass for a
    determined direction. The threshold is therefore ``min_snr`` times
    :math:`[(1 + \sqrt{p/\nu}) / (1 + \sqrt{p/N})]^2`, ``min_snr`` itself for independent entries.

    Returns ``(info, keep, pending)``: the corrected information, the kept directions (columns,
    in scaled coordinates) and the number of directions that look informative but whose
    Jacobian is still too noisy (more replicates decide them).
    """
    M = (B.T @ B) * np.outer(scale, scale)
    Nn = noise * np.outer(scale, scale)
    info = _psd(M - Nn) / np.outer(scale, scale)
    ridge = 1e-9 * max(float(np.trace(Nn)) / len(Nn), 1e-300)
    L = np.linalg.cholesky(0.5 * (Nn + Nn.T) + ridge * np.eye(len(Nn)))
    Linv = np.linalg.inv(L)
    lam, V = np.linalg.eigh(Linv @ M @ Linv.T)
    u = Linv.T @ V                                  # u^T Nn u = 1
    per_scale = (lam - 1.0) / np.maximum(np.sum(u * u, axis=0), 1e-300)
    # a parameter without a prior need only be measurable (a step moves the features by a
    # standard deviation); one with a prior must be informed beyond it
    flat = np.isinf(np.asarray(prior_sd, float))
    share_flat = np.sum(u[flat] ** 2, axis=0) / np.maximum(np.sum(u * u, axis=0), 1e-300)
    need = np.where(share_flat > 0.5, 1.0, s.min_information)
    N, p = B.shape
    nu = min(float(entries), float(N)) if entries > 0 else float(N)
    snr = s.min_snr * ((1.0 + math.sqrt(p / nu)) / (1.0 + math.sqrt(p / max(N, 1)))) ** 2 if N else s.min_snr
    keep = u[:, (lam >= snr) & (per_scale >= need)]
    pending = int(np.sum((lam < snr) & (per_scale >= need)))
    return info, keep, pending


def _concentrated(B: np.ndarray, noise: np.ndarray, rho_rows: np.ndarray, scale: np.ndarray, keep: np.ndarray,
                  s: "EstimateSettings", prior_sd: np.ndarray, alpha: float = 0.01):
    r"""Directions a few entries of the residual determine, which the whole-vector analysis of
    :func:`_information` misses; and the Jacobian and its noise with them.

    The noise of :math:`\hat B` is spread over all :math:`N` entries, while a parameter's signal
    may sit in a few (a static load and a calibration offset move the DC entries of a handful of
    views, an unbalance a line): its signal then drowns in the others' noise in
    :math:`\hat B^T\hat B` (the errors-in-variables correction subtracts that noise's mean, not its
    spread of :math:`\sqrt{2N}` times an entry's). Each row :math:`i` of :math:`\hat B` is tested,
    :math:`t_i^2 = \hat B_i (\rho_i P)^{-1} \hat B_i^T` against :math:`\chi^2_p` at ``alpha``
    over the rows (Bonferroni; :math:`\rho_i P` the row's noise covariance, :math:`\rho_i` its
    group's replay variance); the rows that pass, :math:`T`, are analysed alone as
    :func:`_information` analyses all. Their determined directions outside the span of ``keep``
    join it, and along them the other rows, noise there, are left out of the Jacobian (and of
    its noise): :math:`\hat B_{\bar T} (I - \Pi)` with :math:`\Pi` the projector on the new
    directions (scaled coordinates).

    Returns ``(keep, B, noise)``, unchanged when no row passes or nothing new is determined.
    """
    from scipy import stats

    N, p = B.shape
    rho = float(np.mean(rho_rows)) if len(rho_rows) else 0.0
    if p == 0 or rho <= 0:
        return keep, B, noise
    P = noise / (N * rho)
    try:
        Pinv = np.linalg.inv(0.5 * (P + P.T))
    except np.linalg.LinAlgError:
        return keep, B, noise
    t2 = np.einsum("ij,jk,ik->i", B, Pinv, B) / np.maximum(rho_rows, 1e-300)
    T = t2 > stats.chi2.isf(alpha / N, p)
    if not T.any() or T.all():
        return keep, B, noise
    S = np.outer(scale, scale)
    NnT = float(np.sum(rho_rows[T])) * P
    _, keepT, _ = _information(B[T], NnT, scale, s, prior_sd)
    if keepT.shape[1] == 0:
        return keep, B, noise
    QG, _ = _basis(keep, p)
    R = keepT / np.linalg.norm(keepT, axis=0)
    R = R - QG @ (QG.T @ R)
    new = R[:, np.linalg.norm(R, axis=0) > 0.5]
    if new.shape[1] == 0:
        return keep, B, noise
    Qn, _ = _basis(new, p)
    Pi = Qn @ Qn.T
    I = np.eye(p)
    Bs = B * scale
    Bs[~T] = Bs[~T] @ (I - Pi)
    NnR = float(np.sum(rho_rows[~T])) * (P * S)
    noise_eff = (NnT * S + (I - Pi) @ NnR @ (I - Pi)) / S
    keep_out = np.concatenate([keep, new / np.sqrt(np.maximum(np.einsum("ij,jk,ki->i", new.T, NnT * S, new), 1e-300))],
                              axis=1)
    return keep_out, Bs / scale, noise_eff


def _row_noise(C: np.ndarray, groups, rho: float) -> np.ndarray:
    """Per entry of the residual, the variance of one replay (the centre runs ``C``), pooled over
    its group (the groups' means; ``rho`` when there are too few runs)."""
    n = C.shape[1]
    if len(C) < 2:
        return np.full(n, rho)
    v = C.var(axis=0, ddof=1)
    out = np.full(n, float(np.mean(v)))
    for g in groups or []:
        if len(g):
            out[g] = float(np.mean(v[g]))
    return out


def _solve_step(a, B, info, keep, lam, theta, prob: Problem, s: EstimateSettings, trust: float,
                want_full: bool = False):
    """The Gauss-Newton step on the surrogate (with prior), restricted to the kept directions
    (:func:`_information`), shortened to the bounds and the trust region (``want_full``: also the
    step shortened to the bounds only, whose size decides convergence).

    A parameter on a bound whose step would leave the box is held there (an active set: the
    step is solved again on the kept directions that leave it alone) -- shortening the whole
    step to the box instead would stop every other parameter with it (a dead time fitted to 0
    froze a joint refit of fourteen parameters).
    """
    scale = _scale(prob)
    p = len(theta)
    if keep.shape[1] == 0:
        return (np.zeros(p), np.zeros(p)) if want_full else np.zeros(p)
    g = (B.T @ a + lam * (theta - prob.theta0)) * scale          # scaled gradient
    Hs = (info + np.diag(lam)) * np.outer(scale, scale)
    eps = 1e-9 * np.asarray(prob.step, float)
    at_lo, at_hi = theta <= prob.lower + eps, theta >= prob.upper - eps
    held = np.zeros(p, bool)
    d = np.zeros(p)
    for _ in range(p):
        K = keep
        if held.any():
            from scipy.linalg import null_space

            ns = null_space(keep[held])
            if ns.shape[1] == 0:
                return (np.zeros(p), np.zeros(p)) if want_full else np.zeros(p)
            K = keep @ ns
        z = -np.linalg.lstsq(K.T @ Hs @ K, K.T @ g, rcond=None)[0]
        d = (K @ z) * scale
        d[held] = 0.0
        out = ~held & ((at_lo & (d < 0)) | (at_hi & (d > 0)))
        if not out.any():
            break
        held |= out
    def shrink(d, radius):
        # shorten the step along its own direction to the box (keeps it in the kept subspace)
        lo = np.minimum(np.maximum(prob.lower - theta, -radius), 0.0)
        hi = np.maximum(np.minimum(prob.upper - theta, radius), 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(d > 0, hi / d, np.where(d < 0, lo / d, np.inf))
        return d * min(1.0, float(np.min(f)))
    full = shrink(d, np.inf)
    if want_full:
        return shrink(full, trust * s.max_step * prob.step), full
    return shrink(full, trust * s.max_step * prob.step)


def _scale(prob: Problem) -> np.ndarray:
    """Natural scale of each parameter: its prior standard deviation, else its step."""
    sd = np.asarray(prob.prior_sd, float)
    return np.where(np.isfinite(sd), sd, prob.step)


def _centre(prob: Problem, theta: np.ndarray, k: int, s: EstimateSettings, runs: list) -> tuple[np.ndarray, int]:
    """``centre_runs`` evaluations at ``theta`` with distinct seeds: the feasible ones (also added
    to ``runs``) and the number of infeasible ones."""
    base = prob.seed0 + 1000 * k
    out = prob.batch([(theta.copy(), base + 500 + j) for j in range(s.centre_runs)])
    ok = [r for r in out if np.all(np.isfinite(r))]
    runs.extend((theta.copy(), r) for r in ok)
    return (np.array(ok) if ok else np.zeros((0, len(out[0]) if out else 0))), len(out) - len(ok)


def _pairs(prob: Problem, theta: np.ndarray, k: int, s: EstimateSettings, runs: list) -> tuple[int, int]:
    r"""The design around ``theta`` (added to ``runs``): mirror pairs :math:`\theta \pm h \odot z_j`.

    ``design: axes`` perturbs one parameter at a time (:math:`z_j = e_j`); ``design: signs``
    perturbs all at once (:math:`z_j \in \{\pm1\}^p`: the rows of an orthogonal array, ``n``
    pairs for the smallest power of two ``n > p``, signs and order drawn per iteration, the
    columns too with a ``design_seed``): each run
    then informs every column of the Jacobian, and the regression's :math:`X^TX = 2nh^2 I` is
    ``n`` times larger per parameter than with the axes (the simultaneous-perturbation
    advantage) -- the noise of a weakly determined valley drops below its signal. A mirror pair
    shares one seed (common random numbers); the pair's midpoint is the centre, so curvature does
    not bias the slope. ``pair_runs`` replicates the design with other seeds. An infeasible run
    is left out (its mirror stays: near a stability margin one side of a pair may drop the body
    in every pair, and the feasible side still informs the slope).

    Returns ``(infeasible, total)``: the runs left out and the runs.
    """
    base = prob.seed0 + 1000 * k
    p = len(theta)
    if s.design == "signs" and p > 1:
        # an orthogonal array: p columns of a Hadamard matrix of order n > p (not the all-ones
        # one), with random column signs and row order per iteration -- X^T X = 2 n h^2 I exactly
        from scipy.linalg import hadamard

        n = 1 << int(np.ceil(np.log2(p + 1)))
        ds = int(s.design_seed)
        rng = np.random.default_rng([abs(int(prob.seed0)), int(k)] + ([ds] if ds else []))
        cols = 1 + (rng.permutation(n - 1)[:p] if ds else np.arange(p))
        H = hadamard(n)[:, cols] * rng.choice([-1.0, 1.0], size=p)
        Z = np.concatenate([H[rng.permutation(n)] for _ in range(s.pair_runs)])
    else:
        Z = np.tile(np.eye(p), (s.pair_runs, 1))
    tasks = []
    for j, z in enumerate(Z):
        for sign in (1.0, -1.0):
            t = np.clip(theta + sign * prob.step * z, prob.lower, prob.upper)
            if np.any(t != theta):
                tasks.append((t, base + j))
    res = prob.batch(tasks)
    ok = [np.all(np.isfinite(r)) for r in res]
    runs.extend((t, r) for (t, _), r, good in zip(tasks, res, ok) if good)
    return len(ok) - sum(ok), len(ok)


def _unseen(prob: Problem, keep: np.ndarray, growth: float = 4.0, every: bool = False) -> np.ndarray:
    """The parameters that may be probed (:attr:`Problem.probe`; ``every``: all) of which the
    determined directions ``keep`` (scaled coordinates) hold less than half, and whose grown step
    still fits a quarter of their range."""
    p = len(prob.step)
    probe = np.isinf(np.asarray(prob.prior_sd, float)) if prob.probe is None else np.asarray(prob.probe, bool)
    if every:
        probe = np.ones(p, bool)
    Q, _ = _basis(keep, p)
    held = np.sum(Q ** 2, axis=1)
    span = np.asarray(prob.upper, float) - np.asarray(prob.lower, float)
    room = np.asarray(prob.step, float) * growth <= 0.25 * span
    return probe & (held < 0.5) & room


def _margin(n: int, q: float, cost: float | None = None) -> float:
    r"""Two standard deviations of :math:`\|a_1\|^2 - \|a_0\|^2` for two anchors with the same
    expectation (noise variance :math:`q` per entry each, :math:`n` entries). With
    :math:`a = \mu + e`, :math:`\mathrm{var} = 8q\|\mu\|^2 + 4nq^2`; ``cost`` is
    :math:`\|\mu\|^2` (at least :math:`n`: the data's own noise is in :math:`\mu`), the anchor's
    cost. Far above the noise floor the first term grows with the misfit: a margin computed at
    the floor there rejects steps for the anchors' noise alone."""
    c = max(float(cost), float(n)) if cost is not None else float(n)
    return 2.0 * float(np.sqrt(8 * c * q + 4 * n * q * q))


def _basis(keep: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal bases of the kept directions and of their complement (scaled coordinates).

    The kept vectors are normalised first: their lengths span many orders of magnitude (a
    direction the data pin down to 1e-6 of its tolerance is short), which must not make them
    look dependent.
    """
    if keep.shape[1] == 0:
        return np.zeros((p, 0)), np.eye(p)
    K = keep / np.linalg.norm(keep, axis=0)
    U, sv, _ = np.linalg.svd(K, full_matrices=True)
    k = int(np.sum(sv > 1e-8 * sv[0]))
    return U[:, :k], U[:, k:]


def _sandwich(info: np.ndarray, noise: np.ndarray, keep: np.ndarray, lam: np.ndarray, B: np.ndarray,
              scale: np.ndarray, reps: np.ndarray, m: int, groups, resid: np.ndarray | None = None,
              misfit: bool = False) -> tuple:
    r"""Covariance of the estimate, with the noise the replicates measure.

    The estimate moved only along the kept directions (:func:`_information`); along the others
    it is where the prior holds it. In scaled coordinates (prior standard deviations, or steps)
    the prior is isotropic over the parameters that have one, so the two parts separate: on the
    kept subspace :math:`Q` the sandwich of the data (below), on its complement :math:`Q_c` the
    prior, :math:`(Q_c^T \Lambda Q_c)^{+}`. A parameter without a prior (an effect's) that lies
    mostly outside :math:`Q` was not estimated: its variance is unbounded (:math:`10^{12}` scale
    units) and it is left out.

    **The noise.** The replicates ``reps`` (runs at the final centre with distinct seeds)
    measure the noise of one replay per entry; a rig is one replay of the same physics, so the
    anchor :math:`a = \text{model mean} - \text{data}` has per-entry variance
    :math:`\sigma_j^2 (1 + 1/m)` -- the noise the within-record estimates cannot see included (a
    replay's random hysteresis and current-loop state, intermittent duty saturation at
    excitation peaks). Pooled per group (median, corrected for the median of a
    :math:`\chi^2_{r-1}/(r-1)`; a one-entry group's variance itself) and never below the assumed
    unit, it gives :math:`\Sigma = \mathrm{diag}(\sigma^2)` and on :math:`Q` the sandwich
    :math:`H^{-1}(B_Q^T\Sigma B_Q - \bar\sigma^2 N_{B,Q} + \Lambda_Q)H^{-1}`,
    :math:`H = Q^T(\hat{\mathcal I} + \Lambda)Q`, plus what the complement's prior spread does to
    the kept estimate through the coupling :math:`B_Q^T B_{Q_c}` (the complement is held at the
    prior mean, the truth is anywhere in the prior: a weakly seen parameter biases a well seen
    one), :math:`G P_c G^T`, :math:`G = H^{-1} B_Q^T B_{Q_c}`.

    **Correlated replay noise.** A replay's own state (hysteresis, the current loops, the
    self-sensing's rectified noise) moves many entries of a view together, which a diagonal
    :math:`\Sigma` does not see. The replicates measure it where it matters, projected on the
    kept directions: :math:`S = (1 + 1/m)\,\mathrm{cov}_s(B_Q^T r_s)`. Where :math:`S` exceeds
    the diagonal meat beyond its own sampling noise, the excess is added (:func:`_excess`;
    measured on a rig with every
    physical parameter at its truth: the DCM calibration gain's standard error 2.5 times the
    diagonal one, and the estimate 4.7 diagonal standard errors from its truth).

    **The Jacobian's own noise.** The estimate is the fixed point of the step with the
    *estimated* Jacobian :math:`\hat B = B + E`: :math:`\hat B^T \hat a = 0` at the residual
    :math:`\hat a` there, which puts it :math:`H^{-1}E^T\hat a` from the fixed point of the true
    :math:`B`. :math:`E` comes from the pairs' replays, independent of :math:`\hat a`, so this adds
    :math:`(\|\hat a\|^2/N)\,N_B` to the meat (:math:`N_B = N\rho(X^TX)^{-1}`, ``noise``;
    ``resid``: :math:`\hat a`, the anchor moved by the last step; at least the noise level
    :math:`\bar\sigma^2`, where the term gives back the :math:`\bar\sigma^2 N_B` the
    errors-in-variables correction took out of :math:`\hat B^T\Sigma\hat B`): where the model
    misfits, the Jacobian's noise moves the estimate in proportion to the misfit. In the
    reported covariance only (``misfit``).
    **Misfit** (``misfit=True``: the covariance reported with the final model, which also
    holds the correlated replay noise above; a search's intermediate fits use the diagonal
    noise model, whose identifiability -- what the data inform -- decides which parameters
    are refitted with each candidate). Where the residual at the estimate is larger than the noise
    the replicates measure -- an effect or a parameter the model lacks -- the data's scatter
    about the model is that residual: a group's variance is its mean square over the
    residual's degrees of freedom, :math:`\|\hat a_g\|^2/(n_g(1 - k/N))` with :math:`k` the
    kept directions, when that is the larger (the reduced chi-square scale factor of weighted
    least squares, per view).

    Returns ``(cov, factors)`` in parameter units.
    """
    r = len(reps)
    v = reps.var(axis=0, ddof=1) * (1.0 + 1.0 / m)
    med = (1 - 2 / (9 * (r - 1))) ** 3
    sig = np.ones(v.shape[0])
    facs = []
    for g in (groups or [np.arange(v.shape[0])]):
        if len(g):
            f = max(float(np.median(v[g])) / (med if len(g) > 1 else 1.0), 1.0)
            if misfit and resid is not None:
                dof = max(1.0 - keep.shape[1] / len(resid), 0.5)
                f = max(f, float(np.mean(resid[g] ** 2)) / dof)
            sig[g] = f
            facs.append(f)
    p = len(scale)
    S = np.outer(scale, scale)
    Q0, _ = _basis(keep, p)
    idx = np.flatnonzero((lam > 0) | (np.sum(Q0 ** 2, axis=1) > 0.5))
    sub = np.ix_(idx, idx)
    Q, Qc = _basis(keep[idx], len(idx))
    Ls = np.diag((lam * scale ** 2)[idx])
    Bq = (B * scale)[:, idx] @ Q
    Hk = Q.T @ ((info * S)[sub] + Ls) @ Q
    meat = _psd(Bq.T @ (Bq * sig[:, None]) - float(np.mean(sig)) * Q.T @ (noise * S)[sub] @ Q)
    if misfit:
        # the replicates' noise is correlated across entries (one replay's hysteresis and loop
        # state move whole views together): projected on the kept directions it may exceed what
        # the diagonal above gives -- the excess joins the meat
        P = Bq.T @ (reps - reps.mean(axis=0)).T
        meat = meat + _excess((1.0 + 1.0 / m) * (P @ P.T) / max(r - 1, 1), meat, r - 1)
    meat = meat + Q.T @ Ls @ Q
    # the Jacobian's noise times the residual: at the noise level, or at the misfit
    if misfit:
        ms = float(np.mean(sig)) if resid is None else max(float(np.mean(sig)), float(resid @ resid) / len(resid))
        meat = meat + ms * Q.T @ (noise * S)[sub] @ Q
    Hki = np.linalg.inv(0.5 * (Hk + Hk.T)) if len(Hk) else Hk
    Pc = np.linalg.pinv(Qc.T @ Ls @ Qc, rcond=1e-6, hermitian=True)
    # the complement sits at the prior mean while the truth is anywhere in the prior: through the
    # information coupling the two subspaces (unbiased from the raw Jacobian, whose noise does
    # not correlate between distinct pairs) it biases the kept part
    Bc = (B * scale)[:, idx] @ Qc
    G = Hki @ (Bq.T @ Bc)
    cov_r = Q @ (Hki @ meat @ Hki + G @ Pc @ G.T) @ Q.T + Qc @ Pc @ Qc.T
    cov_s = np.zeros((p, p))
    cov_s[sub] = cov_r
    out = np.setdiff1d(np.arange(p), idx)
    cov_s[out, out] = 1e12
    return cov_s * S, facs


def _excess(S: np.ndarray, M: np.ndarray, dof: int, level: float = 0.95) -> np.ndarray:
    r"""What a replicate covariance ``S`` (``dof`` degrees of freedom) holds beyond ``M``.

    In the coordinates where :math:`M = I`, the directions whose variance :math:`\lambda`
    (eigenvalues of :math:`M^{-1/2} S M^{-1/2}`) exceeds the ``level`` quantile of
    :math:`\chi^2_{dof}/dof` -- more than ``S``'s own sampling noise would give if ``M`` were
    right -- contribute :math:`(\lambda - 1)` along them; the others nothing (adding the
    positive part of noise would inflate every error).
    """
    from scipy import linalg, stats

    if dof < 1 or not len(M):
        return np.zeros_like(M)
    Ms = 0.5 * (M + M.T)
    Ms = Ms + 1e-12 * max(float(np.trace(Ms)) / len(Ms), 1e-300) * np.eye(len(Ms))
    lam, V = linalg.eigh(0.5 * (S + S.T), Ms)        # S V = M V diag(lam), V^T M V = I
    keep = lam > stats.chi2.ppf(level, dof) / dof
    X = Ms @ V[:, keep]
    return (X * (lam[keep] - 1.0)) @ X.T


def _psd(A: np.ndarray) -> np.ndarray:
    """The nearest positive semi-definite matrix (negative eigenvalues set to zero)."""
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    return (V * np.maximum(w, 0.0)) @ V.T


def _widened_design(prob, theta, k, s, runs, log, base_step, grow):
    """The steps of the parameters ``grow`` widened by ``s.probe_growth`` (in place) and the
    design redone at ``theta``: returns the design's index, its infeasible runs and the
    widened parameters' names."""
    base_step[grow] *= s.probe_growth
    k, bad = _design(prob, theta, k + 1, s, runs, log, base_step)
    return k, bad, [prob.names[i] for i in np.flatnonzero(grow)]


def _design(prob: Problem, theta: np.ndarray, k: int, s: EstimateSettings, runs: list, log,
            base: np.ndarray) -> tuple[int, int]:
    """The mirror pairs at ``theta`` (:func:`_pairs`) with the steps ``base``; while more than half
    of their runs are infeasible (a step :math:`h` long enough to drop the body on a stop), the
    steps are halved and the pairs redone, at most ``max_refresh`` times. The halving holds for
    this centre only (the next design starts from ``base`` again: a region near a stability
    margin is no reason to measure the slopes in the noise everywhere after). Returns
    ``(k, infeasible runs)``: the last design's seed index and the runs left out."""
    bad_runs = 0
    prob.step = np.array(base, float)
    for h in range(s.max_refresh + 1):
        bad, total = _pairs(prob, theta, k, s, runs)
        bad_runs += bad
        if 2 * bad <= total or h == s.max_refresh:
            return k, bad_runs
        prob.step = prob.step * 0.5
        k += 1
        if log is not None:
            log(f"  {bad} of {total} design runs infeasible (a stop hit, or outside the physical domain): "
                f"steps halved")
    return k, bad_runs


def _far_above(chi2: float, n: int, floor: float, alpha: float, dof: float = 0.0) -> bool:
    r"""Whether a cost ``chi2`` of ``n`` whitened entries lies beyond the upper ``alpha`` quantile of
    the noise alone, :math:`(f/\nu)\,\chi^2_\nu` with the floor :math:`f` and the noise's
    effective degrees of freedom :math:`\nu` (``dof``, :func:`noise_floor`; ``n`` when 0:
    independent entries) (:class:`EstimateSettings` ``short_alpha``)."""
    from scipy import stats

    nu = float(dof) if dof > 0 else float(n)
    return n > 0 and chi2 > floor / nu * float(stats.chi2.isf(alpha, nu))


def replay_noise(C: np.ndarray, groups) -> tuple[np.ndarray, float, float]:
    r"""What replicate runs ``C`` (``m`` x ``N``, distinct seeds, one point) say of one replay's noise:
    per group of entries the mean variance :math:`\bar v_g`, and the off-diagonal part of
    :math:`\mathrm{tr}\,\Sigma_r^2`, :math:`\sum_{i \ne j}\sigma_{ij}^2`.

    A replay's own state (hysteresis, the current loops, a slow drift of a coil current) moves
    whole views together, so its covariance :math:`\Sigma_r` is not diagonal, and a cost's spread,
    :math:`2\,\mathrm{tr}\,\Sigma^2`, far exceeds that of independent entries. With :math:`W =
    (m-1)S` the scatter matrix of the runs (Wishart, :math:`n = m - 1` degrees of freedom),
    :math:`E\,\mathrm{tr}W^2 = n(n+1)\,t_2 + n\,t_1^2` and :math:`E(\mathrm{tr}W)^2 = n^2 t_1^2 +
    2n\,t_2` (:math:`t_k = \mathrm{tr}\,\Sigma_r^k`), so

    .. math:: \hat t_2 = \frac{n\,\mathrm{tr}W^2 - (\mathrm{tr}W)^2}{n(n+2)(n-1)}

    is unbiased (from the :math:`m \times m` Gram matrix of the centred runs), and so are
    :math:`\frac{n}{n+2}\sum_j \hat v_j^2` for its diagonal part (:math:`E\,\hat v^2 = v^2
    (n+2)/n`) and the difference for its off-diagonal part.

    Returns ``(vg, t2_off, t2_diag)``; the last two NaN with fewer than three runs.
    """
    C = np.asarray(C, float)
    m = len(C)
    v = C.var(axis=0, ddof=1) if m > 1 else np.zeros(C.shape[1] if C.ndim == 2 else 0)
    vg = np.array([float(np.mean(v[g])) if len(g) else 0.0 for g in (groups or [np.arange(len(v))])])
    if m < 3:
        return vg, float("nan"), float("nan")
    X = C - C.mean(axis=0)
    G = X @ X.T
    n = m - 1
    t2 = (n * float(np.sum(G * G)) - float(np.trace(G)) ** 2) / (n * (n + 2) * (n - 1))
    diag = n / (n + 2) * float(v @ v)
    return vg, t2 - diag, diag


def effective_entries(sizes: np.ndarray, vg: np.ndarray, t2_off: float, t2_diag: float) -> float:
    r"""The number of independent entries a replay's noise is worth,
    :math:`\nu = (\mathrm{tr}\,\Sigma_r)^2 / \mathrm{tr}\,\Sigma_r^2` (:func:`replay_noise`'s
    parts; negative off-diagonal estimates count as 0), at most the entries :math:`N`; :math:`N`
    where the parts are unknown. A noise that moves whole views together is worth few."""
    sizes = np.asarray(sizes, float)
    n = float(np.sum(sizes))
    t1 = float(np.sum(sizes * np.asarray(vg, float)))
    if not (np.isfinite(t2_diag) and t2_diag > 0 and t1 > 0):
        return n
    off = float(t2_off) if np.isfinite(t2_off) and t2_off > 0 else 0.0
    return float(min(n, max(1.0, t1 * t1 / (off + t2_diag))))


def noise_floor(sizes: np.ndarray, vg: np.ndarray, t2_off: float, m: int) -> tuple[float, float]:
    r"""The cost the noise alone gives an anchor (the mean of ``m`` replays) and its effective
    degrees of freedom.

    The rig is one more replay of the same physics: where a group's replay variance
    :math:`\bar v_g` (:func:`replay_noise`) exceeds the whitening's unit, the data carry it too.
    The anchor's variance per entry of group :math:`g` is then :math:`d_g = \max(1, \bar v_g) +
    \bar v_g/m`, the cost's mean :math:`f = \sum_g n_g d_g` (:math:`N(1 + \rho/m)` where the
    replays are quieter than the unit), and its variance :math:`2\,\mathrm{tr}\,\Sigma_a^2 \approx
    2[\sum_g n_g d_g^2 + (1 + 1/m)^2 t_{off}]` with :math:`t_{off} = \sum_{i\ne j}\sigma_{ij}^2`
    (``t2_off``, the data carrying the replays' correlations too; negative estimates count as 0):
    the cost is :math:`(f/\nu)\,\chi^2_\nu` with :math:`\nu = f^2/\mathrm{tr}\,\Sigma_a^2`
    (Satterthwaite), :math:`N` for independent entries of equal variance. ``sizes``: the
    groups' entries. Returns ``(f, nu)``.
    """
    sizes, vg = np.asarray(sizes, float), np.asarray(vg, float)
    d = np.maximum(1.0, vg) + vg / m
    f = float(np.sum(sizes * d))
    off = float(t2_off) if np.isfinite(t2_off) and t2_off > 0 else 0.0
    tr2 = float(np.sum(sizes * d * d)) + (1.0 + 1.0 / m) ** 2 * off
    return f, float(min(np.sum(sizes), max(1.0, f * f / tr2)))


def feasible_start(prob: Problem, theta: np.ndarray, seeds: int = 2) -> tuple:
    r"""A start about an infeasible ``theta`` where the replays float, from the prior's spread.

    Where the measured body floats and the model's replay of the same excitation drops it, the
    cost is undefined at the start and a local estimator has nowhere to go (a large excitation
    near the stability margin of the nominal model, on a rig a few tolerances away from it). The
    prior says how far the rig may be from the model, so the
    start is searched for there, on common seeds: each parameter with a prior alone at
    :math:`\theta_j \pm \sigma_j, \pm 2\sigma_j`, and, when none of those floats in every replay,
    :math:`4p` points of a scrambled Sobol sequence over :math:`\theta \pm 2\sigma` (within the
    bounds). Each point is replayed with the same ``seeds`` seeds and ranked by
    :func:`drops_and_cost` (fewest drops, then the lowest cost of the others); the best is
    returned if one of its replays floats. It is a start only: the fit moves from it under the
    prior like from any other.

    Returns
    -------
    (numpy.ndarray or None, int)
        The start (None: no point floats) and the number of points replayed.
    """
    from scipy.stats import qmc

    sd = np.asarray(prob.prior_sd, float)
    free = np.flatnonzero(np.isfinite(sd))
    if not len(free):
        return None, 0
    lo, hi = np.asarray(prob.lower, float), np.asarray(prob.upper, float)
    points = []
    for j in free:
        for z in (1.0, -1.0, 2.0, -2.0):
            th = theta.copy()
            th[j] = np.clip(theta[j] + z * sd[j], lo[j], hi[j])
            if th[j] != theta[j]:
                points.append(th)
    sobol = qmc.Sobol(len(free), scramble=True, seed=int(prob.seed0) % 2 ** 32)
    box = sobol.random(int(2 ** np.ceil(np.log2(4 * len(free)))))[: 4 * len(free)] * 4.0 - 2.0
    spread = [np.clip(_at(theta, free, u * sd[free]), lo, hi) for u in box]
    tried, best = 0, (None, (seeds, float("inf")))
    for stage in (points, spread):
        res = prob.batch([(th, prob.seed0 + 670_000 + j) for th in stage for j in range(seeds)])
        for i, th in enumerate(stage):
            score = drops_and_cost(res[i * seeds:(i + 1) * seeds])
            if score < best[1]:
                best = (th, score)
        tried += len(stage)
        if best[1][0] == 0:
            break
    return (best[0] if best[1][0] < seeds else None), tried


def model_averaged_sd(theta: np.ndarray, var: np.ndarray, alternatives: list) -> tuple[np.ndarray, np.ndarray]:
    r"""Standard errors of an estimate over the models the data do not exclude.

    The chosen model :math:`m_0` gives :math:`\hat\theta` with variances :math:`v_0`; each
    alternative :math:`c` (the same parameters fitted beside one more effect that was not
    accepted) gives :math:`\theta_c, v_c` and its BIC change :math:`\Delta_c` over :math:`m_0`.
    With the models' posterior weights :math:`w_0 = 1`, :math:`w_c = e^{-\Delta_c/2}` (the BIC's
    approximation of the evidence), the mixture's variance about :math:`\hat\theta` is

    .. math:: v = \frac{v_0 + \sum_c w_c\,\big(v_c + (\theta_c - \hat\theta)^2\big)}{1 + \sum_c w_c},

    and the standard error :math:`\sqrt{\max(v_0, v)}`: an effect the held-out test could not
    confirm, but the fitting data do not disfavour, widens the error of every parameter it would
    move (an effect confounded with a calibrated parameter on the data at hand: a small amplifier
    dead time and the self-sensing offset on current pulses), and one the data disfavour barely
    counts.

    Parameters
    ----------
    theta, var : numpy.ndarray
        The chosen model's estimate and variances (p).
    alternatives : list of (numpy.ndarray, numpy.ndarray, float)
        Per alternative ``(theta_c, var_c, delta_bic)``; NaN where a parameter was not refitted
        (taken as the chosen model's).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        The standard errors (p) and the alternatives' weights.

    Examples
    --------
    >>> import numpy as np
    >>> from ssamb.closeloop.estimate import model_averaged_sd
    >>> sd, w = model_averaged_sd(np.zeros(1), np.ones(1), [(np.array([3.0]), np.ones(1), 0.0)])
    >>> float(sd[0] ** 2), float(w[0])     # (1 + (1 + 9)) / 2
    (5.5, 1.0)
    """
    theta, var = np.asarray(theta, float), np.asarray(var, float)
    total, weights = var.copy(), []
    for th, v, dbic in alternatives:
        th, v = np.asarray(th, float), np.asarray(v, float)
        same = ~(np.isfinite(th) & np.isfinite(v))
        th, v = np.where(same, theta, th), np.where(same, var, v)
        w = float(np.exp(-0.5 * np.clip(dbic, -1400.0, 1400.0)))
        weights.append(w)
        total += w * (v + (th - theta) ** 2)
    mixed = total / (1.0 + sum(weights))
    return np.sqrt(np.maximum(var, mixed)), np.array(weights)


def _at(theta: np.ndarray, idx: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``theta`` with ``delta`` added at ``idx``."""
    out = np.asarray(theta, float).copy()
    out[idx] += delta
    return out


def _unmoved(prob: Problem, theta: np.ndarray, lam: np.ndarray, C: np.ndarray, infeasible: int, s) -> MapFit:
    """The result of a fit whose start is infeasible (fewer than two feasible centre runs): the
    start, with the prior's covariance (no prior: unbounded) -- nothing was estimated."""
    p = len(theta)
    var = np.where(lam > 0, 1.0 / np.where(lam > 0, lam, 1.0), 1e12 * np.asarray(prob.step, float) ** 2)
    n = C.shape[1] if C.size else 0
    chi2 = float(np.mean(np.sum(C ** 2, axis=1))) if len(C) else float("inf")
    return MapFit(theta=theta, cov=np.diag(var), cov_misfit=np.diag(var), B=np.zeros((n, p)), info=np.zeros((p, p)),
                  chi2=chi2, n=n, rho=0.0, evaluations=len(C), iterations=0, converged=False,
                  history=[{"infeasible_start": True}], centre_runs=list(C), floor=float(max(n, 1)),
                  stopped_short=True, infeasible=infeasible)


def _no_progress(costs: list, window: int, margin: float) -> bool:
    """True when the last of ``costs`` (the centre's cost at each step tried) is not below the one
    ``window`` steps earlier by more than ``margin``."""
    return window > 0 and len(costs) > window and costs[-1 - window] - costs[-1] < margin


def _local_model(prob: Problem, runs: list, theta: np.ndarray, C: np.ndarray, rhos: list, s: EstimateSettings,
                 entries: float = 0.0):
    """The local model at a centre: the surrogate Jacobian ``B`` and its noise from the pooled
    runs (:func:`_surrogate`), the information and the determined directions (:func:`_information`),
    with the directions a few entries of the residual determine (:func:`_concentrated`).

    Returns ``(B, noise, info, keep, pending, n_local)``, ``n_local`` the directions the
    concentration added."""
    rho = float(np.mean(rhos))
    B, noise = _surrogate(runs, theta, prob.step, s.pool_radius, rho)
    info, keep, pending = _information(B, noise, _scale(prob), s, prob.prior_sd, entries)
    n_global = keep.shape[1]
    keep, B, noise = _concentrated(B, noise, _row_noise(C, prob.groups, rho), _scale(prob), keep, s, prob.prior_sd)
    if keep.shape[1] > n_global:
        sc = np.outer(_scale(prob), _scale(prob))
        info = _psd((B.T @ B - noise) * sc) / sc
    return B, noise, info, keep, pending, keep.shape[1] - n_global


def map_fit(prob: Problem, settings: EstimateSettings | None = None, log: Callable | None = None) -> MapFit:
    """Estimate ``prob`` (see module docstring)."""
    s = settings or EstimateSettings()
    if s.common_seeds > 0 and prob.evaluate is not None:
        return common_seeds_fit(prob, s, log)
    lam = _prior_precision(np.asarray(prob.prior_sd, float))
    theta = np.clip(np.asarray(prob.theta0 if prob.start is None else prob.start, float).copy(), prob.lower, prob.upper)
    prob.step = np.asarray(prob.step, float).copy()
    base_step = prob.step.copy()        # the design's steps (probes, refreshes and widening change them)
    runs: list = []
    C, infeasible = _centre(prob, theta, 0, s, runs)
    dropped = infeasible                # the current centre's infeasible replays
    k = 0
    fb = prob.fallback if prob.fallback is not None else prob.theta0
    fb = np.clip(np.asarray(fb, float), prob.lower, prob.upper)
    if len(C) < 2 and np.any(fb != theta):
        if log is not None:
            log(f"the start is infeasible ({infeasible} of {s.centre_runs} replays hit a stop or leave the physical "
                f"domain): the fallback start")
        theta, k = fb.copy(), 1
        C, bad = _centre(prob, theta, k, s, runs)
        infeasible += bad
        dropped = bad
    if len(C) < 2:
        found, screened = feasible_start(prob, theta)
        if found is not None:
            if log is not None:
                log(f"the start is infeasible ({infeasible} replays at the start and its fallback hit a stop or leave "
                    f"the physical domain): the best of {screened} points of the prior about it that float")
            theta, k = found, k + 1
            C, bad = _centre(prob, theta, k, s, runs)
            infeasible += bad
            dropped = bad
    if len(C) < 2:
        if log is not None:
            log(f"the start is infeasible ({infeasible} replays at the start and its fallback hit a stop or leave the "
                f"physical domain): nothing estimated")
        return _unmoved(prob, theta, lam, C, infeasible, s)
    k, bad = _design(prob, theta, k, s, runs, log, base_step)
    infeasible += bad
    rhos = [float(np.mean(C.var(axis=0, ddof=1)))]
    groups = prob.groups if prob.groups and sum(len(g) for g in prob.groups) == C.shape[1] else None
    spread = [replay_noise(C, groups)]          # per centre: the groups' replay variance, tr(Sigma_r^2)
    a, trust, history, converged, replicates, probes, refresh, widened = C.mean(axis=0), 1.0, [], False, 0, 0, 0, 0
    d = np.zeros(len(theta))
    tried: list = []                    # the centre's cost at each step tried
    best = (theta.copy(), float(a @ a), a, C, dropped)  # the best centre visited: fewest drops, then lowest cost

    sizes = np.array([len(g) for g in (groups or [np.arange(len(a))])], float)

    def pooled() -> tuple:
        # the replays' noise over the centres so far: groups' variances, tr(Sigma_r^2)'s parts
        vg = np.mean([x[0] for x in spread], axis=0)
        parts = np.array([x[1:] for x in spread], float)
        ok = np.isfinite(parts[:, 0])     # both parts are NaN at a centre of fewer than three runs
        off, diag = parts[ok].mean(axis=0) if ok.any() else (float("nan"), float("nan"))
        return vg, float(off), float(diag)

    def floor_dof() -> tuple[float, float]:
        # the cost the noise alone gives and its degrees of freedom (noise_floor): the data's
        # noise per whitened entry, and the anchor's model noise (the mean of len(C) runs)
        vg, off, _ = pooled()
        return noise_floor(sizes, vg, off, len(C))

    def entries() -> float:
        vg, off, diag = pooled()
        return effective_entries(sizes, vg, off, diag)

    def floor() -> float:
        return floor_dof()[0]

    for it in range(s.max_iter + s.short_iter + s.moving_iter):
        fl, dof = floor_dof()
        short = s.short_iter > 0 and _far_above(float(a @ a), len(a), fl, s.short_alpha, dof)
        limit = s.max_iter + (s.short_iter if short else 0)
        its = [h for h in history if "step_norm" in h]
        # on its way: the last step asked for far more than the posterior spread and the one
        # before it removed most of the cost's excess over the floor (a fit beside a larger
        # misfit asks for large steps too, but they do not lower its cost)
        moving = len(its) >= 2 and its[-1]["step_norm"] > s.moving_step and \
            its[-2]["chi2"] - its[-1]["chi2"] > 0.5 * (its[-2]["chi2"] - its[-2]["floor"])
        if it >= limit + (s.moving_iter if moving else 0):
            break
        B, noise, info, keep, pending, n_local = _local_model(prob, runs, theta, C, rhos, s, entries())
        if n_local and log is not None:
            log(f"  {n_local} direction(s) determined by a few entries of the residual")
        grow = _unseen(prob, keep, s.probe_growth) if probes < s.max_probes and it < limit - 1 \
            else np.zeros(len(theta), bool)
        if grow.any():
            # a size no determined direction holds: probe it with a wider step (EstimateSettings)
            probes += 1
            k, bad, names = _widened_design(prob, theta, k, s, runs, log, base_step, grow)
            infeasible += bad
            history.append({"iteration": it, "probe": names, "step_grown_to": prob.step[grow].tolist()})
            if log is not None:
                log(f"iteration {it}: {', '.join(names)} in no determined direction: steps x{s.probe_growth:g}, "
                    "pairs again")
            continue
        d, d_full = _solve_step(a, B, info, keep, lam, theta, prob, s, trust, want_full=True)
        H = info + np.diag(lam)
        # convergence is judged on the step the surrogate asks for, not on the trust region's
        # share of it (repeated rejections shrink that to nothing without reaching an optimum)
        norm = float(np.sqrt(max(d_full @ H @ d_full, 0.0) / len(d)))
        rho = float(np.mean(rhos))
        history.append({"iteration": it, "theta": theta.tolist(), "step": d.tolist(), "chi2": float(a @ a),
                        "rho": rho, "step_norm": norm, "determined_directions": int(keep.shape[1]), "trust": trust,
                        "floor": floor(), "floor_dof": floor_dof()[1]})
        if log is not None:
            log(f"iteration {it}: chi2 {a @ a:.1f} (N {len(a)}, noise floor {floor():.0f}), step {norm:.2f} (posterior "
                f"metric, per parameter), {keep.shape[1]} determined directions")
        if norm >= s.tol and trust < s.min_trust:
            if short and refresh < s.max_refresh:
                # far above the noise, and no step the surrogate proposes improves the fit: its
                # slopes over the finite-difference steps do not describe the cost near the centre
                refresh += 1
                base_step = base_step * 0.5
                trust = 1.0
                k, bad = _design(prob, theta, k + 1, s, runs, log, base_step)
                infeasible += bad
                history[-1]["refreshed"] = True
                if log is not None:
                    log(f"  stalled {a @ a / floor():.3g} times above the noise floor: steps halved, pairs again")
                continue
            history[-1]["stalled"] = True
            if log is not None:
                log(f"  stalled: no step within {trust:.3g} of the trust region improves the fit")
            break
        if norm < s.tol and pending and it < limit - 1 and replicates < s.max_replicates:
            replicates += 1
            # informative directions whose Jacobian is still noise: replicate the pairs here
            k += 1
            _pairs(prob, theta, k, s, runs)
            if log is not None:
                log(f"  {pending} direction(s) informative but not yet above the Jacobian's noise: more pairs")
            continue
        if norm < s.tol:
            grow = _unseen(prob, keep, s.probe_growth, every=True) if short and widened < s.max_refresh \
                else np.zeros(len(theta), bool)
            if grow.any():
                # at rest along the determined directions, yet far above the noise: the others may be
                # informative at a wider step (the Jacobian's signal grows with the step's square,
                # its noise does not), and there the better model lies
                widened += 1
                k, bad, names = _widened_design(prob, theta, k, s, runs, log, base_step, grow)
                infeasible += bad
                history[-1]["widened"] = names
                if log is not None:
                    log(f"  at rest {a @ a / floor():.3g} times above the noise floor: the steps of "
                        f"{', '.join(names)} x{s.probe_growth:g}, pairs again")
                continue
            converged = True
            break
        tried.append(float(a @ a))
        margin = _margin(len(a), rho / max(s.centre_runs, 1), float(a @ a))
        window = s.short_progress_window if it >= s.max_iter and s.progress_window == 0 else s.progress_window
        if _no_progress(tried, window, margin):
            history[-1]["no_progress"] = True
            if log is not None:
                log(f"  no progress: {window} steps lowered the cost by less than its noise")
            break
        k += 1
        # the step tried, in units of the trust region (max_step steps h per coordinate)
        taken = float(np.max(np.abs(d) / (s.max_step * prob.step)))
        Ct, bad = _centre(prob, np.clip(theta + d, prob.lower, prob.upper), k, s, runs)
        infeasible += bad
        if 2 * bad > s.centre_runs or len(Ct) < 2 or bad > dropped:
            # the step left the region where the body floats (or the physical domain): not a
            # cost to compare, a step too long. A model near its stability margin drops the body
            # in some realisations of the loop's noise (the data are one realisation): the step
            # is infeasible when most replays there do, or more than at the current centre (a
            # prediction is the mean of replays, and one that drops the body is no prediction of
            # data in which it floats: the cost of the others cannot buy a drop), and the others
            # make its anchor
            trust = s.reject_shrink * min(trust, taken)
            history[-1]["infeasible"] = bad
            if log is not None:
                log(f"  step infeasible ({bad} of {s.centre_runs} replays hit a stop or leave the physical domain); "
                    f"trust region {trust:.3g}")
            continue
        rhos.append(float(np.mean(Ct.var(axis=0, ddof=1))) if len(Ct) > 1 else 0.0)
        if len(Ct) > 1:
            spread.append(replay_noise(Ct, groups))
        at = Ct.mean(axis=0)
        if bad < dropped or at @ at <= a @ a + _margin(len(a), rho / max(s.centre_runs, 1), float(a @ a)):
            # fewer replays that drop the body come first: the anchors of centres with and without
            # drops average different realisations, and a drop is no misfit a lower cost offsets
            # the region grows when the cost fell by at least a quarter of what the surrogate
            # promised (a surrogate that over-promises keeps its region)
            r_pred = a + B @ d
            promised = float(a @ a - r_pred @ r_pred)
            good = promised <= 0 or float(a @ a - at @ at) >= 0.25 * promised
            theta, a, C, dropped = np.clip(theta + d, prob.lower, prob.upper), at, Ct, bad
            if (dropped, float(a @ a)) < (best[4], best[1]):
                best = (theta.copy(), float(a @ a), a, C, dropped)
            trust = min(s.max_trust, 2 * trust) if good else trust
            replicates = 0
            k, bad = _design(prob, theta, k, s, runs, log, base_step)
            infeasible += bad
        else:
            trust = s.reject_shrink * min(trust, taken)     # the trial's runs stay in the pool and inform B along d
            if log is not None:
                log(f"  step rejected (chi2 {at @ at:.1f}); trust region {trust:.3g}")
    returned = None
    if not converged and best[4] <= dropped and a @ a > best[1] + _margin(len(a), float(np.mean(rhos)) / max(
            s.centre_runs, 1), best[1]):
        # the iterations ran out after steps each within the noise of the cost had taken the
        # centre significantly above the best one it visited: the estimate is that centre
        if log is not None:
            log(f"the last centre's cost {a @ a:.1f} is significantly above the best visited, {best[1]:.1f}: "
                f"the estimate returns there")
        theta, a, C = best[0], best[2], best[3]
        B, noise, info, keep, pending, _ = _local_model(prob, runs, theta, C, rhos, s, entries())
        d, _ = _solve_step(a, B, info, keep, lam, theta, prob, s, trust, want_full=True)
        returned = float(best[1])
    theta_hat = np.clip(theta + d, prob.lower, prob.upper) if converged else theta
    Cf, bad = _centre(prob, theta, k + 1, s, runs)
    infeasible += bad
    reps = np.concatenate([C, Cf]) if len(Cf) else C
    resid = a + B @ (theta_hat - theta)
    cov, facs = _sandwich(info, noise, keep, lam, B, _scale(prob), reps, s.centre_runs, prob.groups, resid=resid)
    cov_m, facs_m = _sandwich(info, noise, keep, lam, B, _scale(prob), reps, s.centre_runs, prob.groups,
                              resid=resid, misfit=True)
    if not converged:
        # the iterations ran out while the estimate was still moving: the last step's size is
        # part of its uncertainty
        cov, cov_m = cov + np.outer(d, d), cov_m + np.outer(d, d)
    fl, dof = floor_dof()
    short = (not converged) and _far_above(float(a @ a), len(a), fl, s.short_alpha, dof)
    if short and log is not None:
        log(f"stopped short: not converged, its cost {a @ a:.1f} is {a @ a / fl:.3g} times the noise floor {fl:.0f}")
    history.append({"noise_factors": facs, "misfit_factors": facs_m, "infeasible": infeasible,
                    "returned_to_best": returned})
    return MapFit(theta=theta_hat, cov=cov, cov_misfit=cov_m, B=B, info=info, chi2=float(a @ a), n=len(a),
                  rho=float(np.mean(rhos)),
                  evaluations=len(runs) + infeasible, iterations=len(history) - 1, converged=converged,
                  history=history, centre_runs=list(reps), floor=fl, floor_dof=dof, stopped_short=short,
                  infeasible=infeasible)


def drops_and_cost(res) -> tuple[int, float]:
    """A point's score from its replays' residuals: the number of infeasible ones (the body
    dropped, NaN) and the cost of the others' mean (infinite when none floats); points are
    ranked by drops first, a drop being no misfit a lower cost offsets."""
    ok = [r for r in res if np.all(np.isfinite(r))]
    a = np.mean(ok, axis=0) if ok else None
    return len(res) - len(ok), float(a @ a) if a is not None else float("inf")


def best_fit(prob: Problem, settings: EstimateSettings | None = None, restarts: int = 1,
             log: Callable | None = None) -> tuple[MapFit, list]:
    r"""The best of ``restarts`` fits of ``prob`` (:func:`map_fit`), each with its own design.

    Fit ``r`` draws its designs with ``design_seed`` :math:`1000 s + r` (:math:`s` the settings'
    own; fit 0 is :func:`map_fit` with the settings as given). Where the cost has flat valleys,
    infeasible regions and a noisy surrogate, where a fit ends depends on its path (which
    perturbation pattern each parameter got); the fits are scored on the same
    ``2 centre_runs`` seeds at their estimates (:func:`drops_and_cost`: fewest replays that drop
    the body, then the lowest cost of the mean of the others -- the fitting data's cost, never
    held-out data), and the best is kept. One restart: :func:`map_fit` alone, nothing scored.

    Returns ``(fit, scores)``: per restart ``{design_seed, drops, cost, floor_ratio,
    stopped_short}``, the kept one first.
    """
    import dataclasses

    s = settings or EstimateSettings()
    if restarts <= 1 or (s.common_seeds > 0 and prob.evaluate is not None):
        # the common-seeds estimate does not depend on a design: one fit
        return map_fit(prob, s, log), []
    step0 = np.asarray(prob.step, float).copy()
    fits, scores = [], []
    for r in range(restarts):
        sr = dataclasses.replace(s, design_seed=1000 * int(s.design_seed) + r) if r else s
        pr = dataclasses.replace(prob, step=step0.copy())
        f = map_fit(pr, sr, (lambda m, r=r: log(f"[{r + 1}/{restarts}] {m}")) if log is not None else None)
        drops, cost = drops_and_cost(pr.batch([(f.theta.copy(), prob.seed0 + 900_000 + j)
                                               for j in range(2 * s.centre_runs)]))
        fits.append(f)
        scores.append({"design_seed": int(sr.design_seed), "drops": drops, "cost": cost,
                       "floor_ratio": f.floor_ratio, "stopped_short": bool(f.stopped_short)})
    best = min(range(restarts), key=lambda j: (scores[j]["drops"], scores[j]["cost"]))
    if log is not None:
        log(f"best of {restarts} fits: {best + 1} (" + "; ".join(
            f"{d['drops']} drops, cost {d['cost']:.4g}" for d in scores) + ")")
    return fits[best], [scores[best]] + [d for j, d in enumerate(scores) if j != best]


def common_seeds_fit(prob: Problem, settings: EstimateSettings, log: Callable | None = None) -> MapFit:
    r"""The estimate of the sample-average problem (:class:`EstimateSettings` ``common_seeds``).

    ``scipy.optimize.least_squares`` (trust region, bounds, forward differences of :math:`10^{-3}`
    of the scale) minimises, in units of the parameters' scale (prior standard deviation, else
    step),

    .. math:: \big\|(1 + n_d(\theta))\,\bar r_S(\theta)\big\|^2 + \|(\theta - \theta_0)/\sigma_p\|^2,

    with :math:`\bar r_S` the mean of the feasible ones of ``common_seeds`` replays on fixed seeds
    and :math:`n_d` the number of infeasible ones (a replay that drops the body is no finite
    difference of the cost: the factor makes every step toward more drops a worse one, none
    floating a cost above any that floats). It starts from the start, or from
    :attr:`Problem.fallback` when most replays drop the body at the start and fewer at the fallback
    (a candidate whose unidentified parameters start at their prior mean, on a device whose
    nominal model drops the body), and from the best point of the prior about it that floats when
    most still drop there (:func:`feasible_start`). The solution replaces the start only when it is no worse on
    ``2 centre_runs`` fresh seeds (:func:`drops_and_cost`: fewer drops, then a lower cost): the
    fresh seeds judge it by the problem's noise, not by the realisation it was fitted to.

    At the estimate :math:`\hat\theta`, the Jacobian :math:`J` of :math:`\bar r_S` (forward
    differences, common seeds: smooth where the replays are) gives the data information
    :math:`\mathcal I = J^TJ/(1 + \rho/S)` (each whitened entry: the data's unit noise and the
    noise of the mean of :math:`S` replays, :math:`\rho` the single replay's variance from
    ``centre_runs`` fresh replays, whose mean is the anchor :math:`a` and the cost
    :math:`\|a\|^2`), the covariance :math:`(\mathcal I + \Lambda)^{-1}`, and with the misfit
    :math:`(\mathcal I/f + \Lambda)^{-1}`, :math:`f = \max(1, \|a\|^2/\text{floor})`. The fit has
    converged when the solver met one of its tolerances; its last entry of ``history`` holds the
    Gauss-Newton step :math:`J` and the prior still ask for, in the posterior metric per
    parameter (``step_norm``: near 0 at an optimum).
    """
    from scipy.optimize import least_squares

    s = settings
    scale = _scale(prob)
    theta0 = np.asarray(prob.theta0, float)
    start = np.clip(np.asarray(theta0 if prob.start is None else prob.start, float), prob.lower, prob.upper)
    sd = np.asarray(prob.prior_sd, float)
    has = np.isfinite(sd)
    lam = _prior_precision(sd)
    S = int(s.common_seeds)
    seeds = [prob.seed0 + 800_000 + j for j in range(S)]
    count = {"runs": 0, "infeasible": 0}

    def mean_of(th):
        rs = prob.batch([(th, sd_) for sd_ in seeds])
        ok = [r for r in rs if np.all(np.isfinite(r))]
        count["runs"] += len(rs)
        count["infeasible"] += len(rs) - len(ok)
        return (np.mean(ok, axis=0) if ok else None), len(rs) - len(ok), len(rs[0])

    def fun(x):
        th = x * scale
        m, drops, n = mean_of(th)
        prior = (th - theta0)[has] / sd[has]
        if m is None:               # nothing floats: above any cost of a point where something does
            return np.concatenate([np.full(n, 1e4), prior])
        return np.concatenate([m * (1.0 + drops), prior])

    fresh = [prob.seed0 + 850_000 + j for j in range(2 * s.centre_runs)]

    def score(th):
        rs = prob.batch([(th, sd_) for sd_ in fresh])
        out = drops_and_cost(rs)
        count["runs"] += len(rs)
        count["infeasible"] += out[0]
        return out
    before = score(start)
    if prob.fallback is not None and before[0] > s.centre_runs:
        # most replays at the start drop the body: the fallback, a point known to float, if it does
        fb = np.clip(np.asarray(prob.fallback, float), prob.lower, prob.upper)
        at_fb = score(fb)
        if at_fb < before:
            start, before = fb, at_fb
    if before[0] > s.centre_runs:
        # still most: a point of the prior about the start that floats (:func:`feasible_start`)
        found, screened = feasible_start(prob, start)
        count["runs"] += 2 * screened
        if found is not None:
            at_found = score(found)
            if at_found < before:
                start, before = found, at_found
                if log is not None:
                    log(f"the start drops the body: the best of {screened} points of the prior about it that float")
    lo, hi = prob.lower / scale, prob.upper / scale
    x0 = np.clip(start / scale, lo, hi)
    res = least_squares(fun, x0, bounds=(lo, np.maximum(hi, lo + 1e-12)), diff_step=1e-3,
                        max_nfev=int(s.common_seeds_evaluations))
    moved = np.clip(res.x * scale, prob.lower, prob.upper)
    after = score(moved)
    keep = after <= before
    theta = moved if keep else start
    if log is not None:
        log(f"common-seeds least squares ({S} seeds, {res.nfev} evaluations): {after[0]} drops, cost "
            f"{after[1]:.4g} on fresh seeds against the start's {before[0]}, {before[1]:.4g}: "
            f"{'kept' if keep else 'the start kept'}")
    # the Jacobian of the mean of the common seeds' replays at the estimate
    r0, d0, n = mean_of(theta)
    p = len(theta)
    J = np.zeros((n, p))
    if r0 is not None:
        for j in range(p):
            h = 1e-3 * scale[j] * (1.0 if theta[j] + 1e-3 * scale[j] <= prob.upper[j] else -1.0)
            th = theta.copy()
            th[j] += h
            rj, dj, _ = mean_of(th)
            if rj is not None and dj == d0:
                J[:, j] = (rj - r0) / h
    C = [r for r in prob.batch([(theta, prob.seed0 + 860_000 + j) for j in range(s.centre_runs)])
         if np.all(np.isfinite(r))]
    count["runs"] += s.centre_runs
    count["infeasible"] += s.centre_runs - len(C)
    if len(C) < 2:
        C = C * 2 if C else [np.full(n, np.nan)] * 2
    C = np.asarray(C)
    a = C.mean(axis=0)
    rho = float(np.mean(C.var(axis=0, ddof=1))) if np.all(np.isfinite(C)) else 0.0
    info = J.T @ J / (1.0 + rho / max(S, 1))
    cov = _inverse(info + np.diag(lam), scale)
    chi2 = float(a @ a) if np.all(np.isfinite(a)) else float("inf")
    fl = n * (1.0 + rho / len(C))
    f = max(1.0, chi2 / fl) if np.isfinite(chi2) else 1.0
    cov_m = _inverse(info / f + np.diag(lam), scale)
    g = J.T @ (r0 if r0 is not None else np.zeros(n)) + lam * (theta - theta0)
    d = -cov @ g
    H = info + np.diag(lam)
    norm = float(np.sqrt(max(d @ H @ d, 0.0) / max(p, 1)))
    converged = bool(res.status > 0) and keep and math.isfinite(after[1])    # not where nothing floats
    short = (not converged) and _far_above(chi2, n, fl, s.short_alpha)
    history = [{"iteration": 0, "theta": start.tolist(), "chi2": float(before[1]), "common_seeds": S},
               {"iteration": 1, "theta": theta.tolist(), "chi2": chi2, "rho": rho, "step_norm": norm,
                "determined_directions": int(np.sum(np.linalg.eigvalsh(info * np.outer(scale, scale))
                                                    >= s.min_information)),
                "solver_status": int(res.status), "kept": bool(keep)},
               {"infeasible": count["infeasible"]}]
    return MapFit(theta=theta, cov=cov, cov_misfit=cov_m, B=J, info=info, chi2=chi2, n=n, rho=rho,
                  evaluations=count["runs"], iterations=int(res.nfev), converged=converged, history=history,
                  centre_runs=list(C), floor=fl, stopped_short=short, infeasible=count["infeasible"])
