r"""The comparison of data and model that every fit and test of close the loop reads.

A :class:`Comparison` holds, for the fitting part and the held-out part of a record, the
feature layout (:mod:`ssamb.closeloop.features`: DC, the excited lines, the lines found in the
residual), the measured features with their noise, and the whitener of a measured-minus-model
difference. Its noise model:

* the **data**: the off-grid covariance of the record, rescaled per view by the
  period-to-period spread (fitting part; the held-out part, with fewer periods, takes the same
  factors);
* the **model**: a prediction is the mean of ``replay_seeds`` replays with distinct seeds (the
  model's expected response); its noise is the off-grid covariance of that mean, rescaled per
  view by the replicates' own spread at the nominal parameters
  (:func:`~ssamb.closeloop.features.replicate_factors`).

The whitener of the difference is built once, from the nominal replay: weights that do not
move with the parameters keep the cost a fixed function of them. (Where the noise at the
estimate differs, the estimator's sandwich covariance accounts for it:
:func:`ssamb.closeloop.estimate.map_fit`.)

Only :meth:`Comparison.prediction` and :meth:`Comparison.residual` touch the model, through
:meth:`ssamb.closeloop.replay.Replayer.run`: parameter overrides, effects and seeds in,
logged channels out.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .data import Record, Split
from .features import (Features, Layout, Whitener, features, low_frequency_from, make_layout, replicate_factors,
                       scale_views)
from .replay import Replayer
from .spectra import Frame, make_frame

__all__ = ["Comparison", "Part", "PartResidual"]

#: models whose noise factors and leave-one-replay-out residuals a comparison keeps
#: (:meth:`Comparison.memoised`)
MEMO_SIZE = 64


@dataclass
class Part:
    """One segment of the record (fitting or held-out): frame, layout, data features, whitener."""

    frame: Frame
    layout: Layout
    data: Features
    whitener: Whitener | None = None
    model_factors: tuple = ()

    @property
    def n_end(self) -> int:
        """Samples a replay needs to cover this part."""
        return self.frame.i0 + self.frame.n


@dataclass(frozen=True)
class PartResidual:
    """The whitened model-minus-data residual over one part, as a picklable callable (what a
    replay worker applies to the channels it simulated: :meth:`Comparison.evaluate_many`).

    Attributes
    ----------
    layout : Layout
    whitener : Whitener
    data : Features
        The measured features of the part.
    stops_infeasible : bool
        A replay whose body hit a stop (``delevitated``) is infeasible: its residual is NaN
        (the data do not hit one, :attr:`Comparison.stops_infeasible`).
    """

    layout: Layout
    whitener: Whitener
    data: Features
    stops_infeasible: bool = False

    @classmethod
    def of(cls, part: Part, stops_infeasible: bool = False) -> "PartResidual":
        return cls(part.layout, part.whitener, part.data, stops_infeasible)

    def infeasible(self) -> np.ndarray:
        """The residual of an infeasible model (NaN in every entry: :class:`ssamb.closeloop.estimate.Problem`)."""
        return np.full(len(self.whitener.residual(self.data, self.data)), np.nan)

    def model_features(self, channels: dict) -> Features:
        """Feature values of model channels (views or channels; no noise: the whitener is fixed).
        A prediction's ``runs`` (its replays' channels, :meth:`Comparison.prediction`) give its
        ``band`` features."""
        dev = self.layout.device
        ch = channels if all(v in channels for v in self.layout.views) else dev.views(channels)
        runs = channels.get("runs") if self.layout.bands else None
        if runs:
            runs = [r if all(v in r for v in self.layout.views) else dev.views(r) for r in runs]
        return features(self.layout, ch, noise=False, runs=runs)

    def __call__(self, channels: dict) -> np.ndarray:
        if self.stops_infeasible and channels.get("delevitated"):
            return self.infeasible()
        return self.whitener.residual(self.model_features(channels), self.data)


@dataclass
class Comparison:
    """Data and model compared on the fitting and the held-out part (module docstring).

    Attributes
    ----------
    record : Record
    split : Split
    replay : Replayer
    seeds : tuple of int
        Seeds of the replays averaged into a prediction.
    floor : numpy.ndarray
        Smallest noise level per cost view of the device (per sample).
    fit, hold : Part
    lines_hz : tuple
        Line frequencies read as features.
    dl_relative : float
        The model's reproducibility at the device's own lines, relative to a line's amplitude
        (``device_line_relative`` of the settings), added to the model's noise there.
    stops_infeasible : bool
        Whether a fit's replay that hits a stop is infeasible (the data do not hit one: such a
        model is not a worse fit of these data but another regime, whose cost says nothing about
        the direction to a better one); its residual, and that of parameters outside the device's
        physical domain (:meth:`ssamb.device.Device.physical`), is NaN in the fits
        (:meth:`evaluator`, :meth:`evaluate_many`).
    """

    record: Record
    split: Split
    replay: Replayer
    seeds: tuple
    floor: np.ndarray
    fit: Part = None
    hold: Part = None
    lines_hz: tuple = ()
    dl_relative: float = 0.0
    stops_infeasible: bool = False
    _nominal: dict = field(default_factory=dict, repr=False)
    _memo: dict = field(default_factory=dict, repr=False)
    _physical: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, record: Record, split: Split, replay: Replayer, seeds, settings) -> "Comparison":
        """Frames of the two parts and the measured features: DC, the excited lines and the device's
        own lines (:meth:`ssamb.device.Device.device_lines_hz`: the AMB's PWM carrier's aliased
        harmonics); lines the excitation lacks are added by :meth:`set_lines`."""
        import dataclasses

        dev = record.device
        fl = dev.floors(settings)
        floor = np.array([fl[v] for v in dev.cost_views])
        ripple = dev.device_lines_hz(replay.cfg, record.fs_hz)
        record = dataclasses.replace(record, device_lines_hz=ripple)
        replay.record = record
        c = cls(record, split, replay, tuple(int(s) for s in seeds), floor,
                dl_relative=float(getattr(settings, "device_line_relative", 0.0)))
        fs, sig, P, lines = record.fs_hz, record.signal, split.n_period, record.lines_hz
        fit_frame = make_frame(fs, split.i0, split.i_fit - split.i0, sig, P, lines)
        hold_frame = make_frame(fs, split.i_fit, split.i_end - split.i_fit, sig, P, lines)
        dlv = tuple(getattr(dev.features, "device_line_views", ()) or ())
        dlf = [fl[v] for v in dlv]
        c.fit = Part(fit_frame, make_layout(fit_frame, sig, ripple, dev.cost_views, device=dev, floor=floor,
                                            exclude_hz=ripple, dl_views=dlv, dl_floor=dlf), None)
        c.hold = Part(hold_frame, make_layout(hold_frame, sig, ripple, dev.cost_views, device=dev, floor=floor,
                                              exclude_hz=ripple, dl_views=dlv, dl_floor=dlf), None)
        c._measure()
        return c

    @property
    def device(self):
        return self.record.device

    def _measure(self) -> None:
        meas = self.device.views(self.record.channels)
        self.fit.data = features(self.fit.layout, meas, self.floor)
        factors = self.fit.data.factors or None
        self.hold.data = self._low_from_fit(features(self.hold.layout, meas, self.floor, factors=factors),
                                            self.fit.data)

    def _low_from_fit(self, f, fit_f):
        """The held-out part's features ``f`` with the fitting part's low-frequency noise
        (:func:`ssamb.closeloop.features.low_frequency_from`) when the record is periodic but the
        held-out part too short to be read as such (fewer than two periods); else ``f``."""
        if not (self.fit.frame.periodic and not self.hold.frame.periodic and self.split.n_period):
            return f
        return low_frequency_from(f, self.hold.layout, fit_f, self.fit.frame.n)

    def set_lines(self, lines_hz) -> None:
        """Read the given line frequencies as features too, beside the device's own (and rebuild
        the whiteners)."""
        self.lines_hz = tuple(float(f) for f in lines_hz)
        for part in (self.fit, self.hold):
            part.layout = part.layout.with_lines(self.record.device_lines_hz + self.lines_hz)
        self._measure()
        if self._nominal:
            self.calibrate_noise(**self._nominal)

    # -- the model ---------------------------------------------------------------------------
    def prediction(self, overrides=None, effects=(), n: int | None = None) -> dict:
        """The model's expected channels: the mean of the replays with :attr:`seeds`, with the share
        of them whose body touched a stop (``delevitated_share``). When the comparison reads power
        spectra (``band`` features), the replays' channels too (``runs``): the density of a mean of
        replays holds only a fraction of their noise."""
        out = self.replay.mean(effects, n, overrides, self.seeds)
        runs = self.replay.runs(effects, n, overrides, self.seeds)
        out["delevitated_share"] = float(np.mean([bool(r["delevitated"]) for r in runs]))
        if self.fit is not None and (self.fit.layout.bands or self.hold.layout.bands):
            out["runs"] = [{c: r[c] for c in self.device.channels} for r in runs]
        return out

    def calibrate_noise(self, overrides=None, effects=()) -> None:
        """Whiteners of both parts from the replays at ``overrides``/``effects`` (the nominal model).

        The per-view factors of the replicates' spread (single replays, fitting part) scale the
        off-grid covariance of the mean of the replays.

        A part without a periodic excitation reads the data's noise off the residual of the data
        from that mean (:meth:`_residual_noise`), not off the data alone: the response to a
        random excitation leaks across Welch segments (a pulse's tail into the next segment),
        deterministic content the data and the model share, which the regression on the
        excitation per segment counts as noise.
        """
        self._nominal = {"overrides": overrides, "effects": tuple(effects)}
        runs = [self.device.views(r) for r in self.replay.runs(effects, None, overrides, self.seeds)]
        mean = {v: np.mean([r[v] for r in runs], axis=0) for v in runs[0]}
        if not self.fit.frame.periodic or not self.hold.frame.periodic:
            self._measure()
            self._residual_noise(mean, len(runs))
        ones = (np.ones(len(self.device.cost_views)), np.ones(len(self.device.cost_views)))
        fac_fit = replicate_factors([features(self.fit.layout, r) for r in runs]) if len(runs) >= 3 else None
        self.hold.data = self._low_from_fit(self.hold.data, self.fit.data)
        fm_fit = None
        for part in (self.fit, self.hold):
            fac = fac_fit
            if part is self.hold and fac is not None and (part.layout.n_win or part.layout.bands):
                # the replicates' spread of windows and bands depends on the part's length
                fac = tuple(fac_fit[:2]) + tuple(replicate_factors([features(part.layout, r) for r in runs])[2:])
            fm = features(part.layout, mean, factors=ones, runs=runs)
            if fac is not None:
                fm = scale_views(fm, *fac)
            if fm.dl.size and self.dl_relative > 0:
                # the model's reproducibility at the device's lines, relative to their amplitude
                import dataclasses

                extra = (self.dl_relative * np.abs(fm.dl)) ** 2
                fm = dataclasses.replace(fm, cov_dl=fm.cov_dl + np.einsum("lv,vw->lvw", extra, np.eye(extra.shape[1])))
            if part is self.fit:
                fm_fit = fm
            else:
                fm = self._low_from_fit(fm, fm_fit)
            part.model_factors = fac or ()
            part.whitener = Whitener.build(part.layout, part.data, fm)

    def _residual_noise(self, mean: dict, m: int) -> None:
        r"""The data's noise of a part without a periodic excitation, from the residual of the data
        from the mean of ``m`` replays: its covariances (DC, cross-spectra, lines, windows) hold the
        data's noise and the mean's, :math:`(1 + 1/m)` times the data's when the rig and a replay
        are alike; the data's bands keep their own (log densities of the data itself)."""
        import dataclasses

        meas = self.device.views(self.record.channels)
        res = {v: meas[v] - mean[v] for v in mean}
        k = m / (m + 1.0)
        for part in (self.fit, self.hold):
            if part.frame.periodic:
                continue
            fr = features(part.layout, res, self.floor)
            part.data = dataclasses.replace(part.data, cov_dc=fr.cov_dc * k, cov_bins=fr.cov_bins * k,
                                            cov_lines=fr.cov_lines * k, cov_win=fr.cov_win * k, cov_dl=fr.cov_dl * k)

    def model_features(self, part: Part, channels: dict) -> Features:
        """Feature values of model channels (views or channels) over a part (no noise: the
        whitener is fixed)."""
        return PartResidual.of(part).model_features(channels)

    def residual(self, part: Part, channels: dict) -> np.ndarray:
        """Whitened model-minus-data residual of ``channels`` over ``part``."""
        return PartResidual.of(part)(channels)

    def evaluator(self, part: Part, build):
        """``(theta, seed) -> residual`` of a single replay whose overrides and effects ``build(theta)``
        returns (``(overrides, effects)``), for :func:`ssamb.closeloop.estimate.map_fit`."""
        post = PartResidual.of(part, self.stops_infeasible)

        def evaluate(theta, seed):
            ov, eff = build(theta)
            if self._unphysical(ov):
                return post.infeasible()
            return post(self.replay.run(eff, part.n_end, ov, seed, cache=False))
        return evaluate

    def _unphysical(self, overrides) -> str | None:
        """Why the model with ``overrides`` lies outside the device's physical domain (None: inside);
        the answer for one parameter set is kept (a fit replays it with several seeds)."""
        from ..config import overridden

        if not overrides:
            return None
        key = tuple(sorted((k, float(v)) for k, v in overrides.items()))
        if key not in self._physical:
            self._physical[key] = self.device.physical(overridden(self.replay.cfg, overrides))
            while len(self._physical) > MEMO_SIZE:
                self._physical.pop(next(iter(self._physical)))
        return self._physical[key]

    def evaluate_many(self, part: Part, build):
        """``[(theta, seed), ...] -> [residual, ...]``: :meth:`evaluator` over a batch, on the
        replayer's workers (a fit's design is independent replays; ``build`` runs here, the
        replays and their residuals in the workers)."""
        post = PartResidual.of(part, self.stops_infeasible)

        def many(tasks):
            jobs = [(eff, part.n_end, ov, seed) for (ov, eff), seed in ((build(th), s) for th, s in tasks)]
            ok = [i for i, j in enumerate(jobs) if not self._unphysical(j[2])]
            res = self.replay.map_runs([jobs[i] for i in ok], post) if ok else []
            out = [post.infeasible() for _ in jobs]
            for i, r in zip(ok, res):
                out[i] = r
            return out
        return many

    def memoised(self, kind: str, part: Part, overrides, effects, compute):
        """``compute()``, kept per ``kind``, part and model (``overrides``, ``effects``, :attr:`seeds`)
        while the part's layout, data and whitener stay the objects they were: the replays of a
        model are deterministic, so what is read off them is too, and a search compares one base
        with many candidates. The last :data:`MEMO_SIZE` are kept."""
        key = (kind, id(part), Replayer._key([dict(e) for e in effects], None,
                                              {k: float(v) for k, v in sorted((overrides or {}).items())},
                                              list(self.seeds)))
        state = (part.layout, part.data, part.whitener)
        hit = self._memo.pop(key, None)
        if hit is not None and all(a is b for a, b in zip(hit[0], state)):
            self._memo[key] = hit
            return hit[1]
        value = compute()
        self._memo[key] = (state, value)
        while len(self._memo) > MEMO_SIZE:
            self._memo.pop(next(iter(self._memo)))
        return value

    def noise_factors(self, part: Part, overrides=None, effects=()) -> np.ndarray:
        r"""Per-entry factor of the noise of a prediction's residual over its assumed unit.

        From the replays averaged into the prediction (:attr:`seeds`): the variance of their
        whitened residuals times :math:`1 + 1/m` (the data are one more replay of the same
        physics), pooled per group (:meth:`groups`: the median, corrected for the median of
        :math:`\chi^2_{m-1}/(m-1)`; a one-entry group's variance itself), never below 1
        (:func:`ssamb.closeloop.estimate._sandwich` reads replicates the same way). A device line
        (the PWM's aliased lines in a controller output) has its own factor where its replicates
        spread more than its group's: their spread grows with the line's frequency and along the
        record, and a pooled factor lets those few entries decide every held-out comparison (the
        validation page has the measured case).
        """
        return self.memoised("noise_factors", part, overrides, effects,
                             lambda: self._noise_factors(part, overrides, effects)).copy()

    def _noise_factors(self, part: Part, overrides, effects) -> np.ndarray:
        reps = np.array([self.residual(part, r) for r in self.replay.runs(effects, None, overrides, self.seeds)])
        m = len(reps)
        out = np.ones(reps.shape[1])
        if m < 3:
            return out
        v = reps.var(axis=0, ddof=1) * (1.0 + 1.0 / m)
        med = (1 - 2 / (9 * (m - 1))) ** 3
        for g in self.groups(part):
            out[g] = max(float(np.median(v[g])) / (med if len(g) > 1 else 1.0), 1.0)
        for idx in _device_line_pairs(part.whitener.labels):
            out[idx] = max(float(np.mean(v[idx])), float(out[idx[0]]))
        return out

    def groups(self, part: Part) -> list:
        """Entries of the whitened residual that share a noise level: per view, its DC entry
        (a replay's random state -- hysteresis, the current loops' integrators, intermittent duty
        saturation -- moves DC far more than the within-record noise shows), its windows (slow
        trends: the same), its bands (log densities) and its other entries."""
        return list(self.named_groups(part).values())

    def named_groups(self, part: Part) -> dict:
        """:meth:`groups` by name, ``view:kind`` (kind ``dc``, ``win``, ``band`` or ``lines`` for
        the excited lines and line features)."""
        g = part.whitener.groups()
        special = {k: set(g[k].tolist()) for k in ("dc", "win", "band")}
        other = set().union(*special.values())
        out = {}
        for v in part.layout.all_views:
            idx = g.get("view:" + v, np.zeros(0, int))
            out[f"{v}:lines"] = np.array([i for i in idx if i not in other], int)
            for k in ("dc", "win", "band"):
                out[f"{v}:{k}"] = np.array([i for i in idx if i in special[k]], int)
        return {k: x for k, x in out.items() if len(x)}


def _device_line_pairs(labels: list) -> list:
    """Index arrays of the whitened vector's device-line entries, one per view and line (its real
    and imaginary parts), from a whitener's ``labels`` (``(group, view, frequency)``)."""
    pairs: dict = {}
    for i, (g, v, f) in enumerate(labels):
        if g == "dl":
            pairs.setdefault((v, f), []).append(i)
    return [np.asarray(ix, int) for ix in pairs.values()]
