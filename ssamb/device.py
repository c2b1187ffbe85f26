r"""The device interface: what close the loop needs of a physical device, in one place.

Close the loop (:mod:`ssamb.closeloop`) compares a device's measured data with its model, calibrates
the model's nominal parameters and looks for the physical effects the model lacks. It knows a device
only through a :class:`Device`:

* **data**: the measured channels (names, units, sampling), a loader for the file formats a user
  of that device has (:meth:`Device.load`), a validator that names the file and column of bad data
  (:meth:`Device.validate`), plausibility notes on data that are valid but suspicious
  (:meth:`Device.notes`), and the :class:`Record` built from the arrays (:meth:`Device.record`):
  channels, the excitation that drives a replay, and what the analysis may use;
* **views**: the channels as the comparison sees them (:meth:`Device.views`: e.g. the AMB's
  differential and common-mode coil currents), the views that enter the cost (``cost_views``),
  their units, and groups of channels whose errors are also reported pooled;
* **replay**: parameters (dotted config keys), effects and a seed in, the logged channels out
  (:meth:`Device.replay`): the model driven by what the record says drove the rig;
* **priors**: the calibratable nominal parameters with their tolerances (:meth:`Device.priors`);
* **effects**: the device's effect library, one module per effect (:attr:`Device.effects`,
  :class:`EffectModule`): its parameters and their validation, how it enters the replay, the
  signature it leaves in the residual and the evidence for it, its parameterisation for fitting
  (:class:`EffectModel`) and its entry in ``closeloop.json``;
* **features**: which paths, axes and lines the residual analysis reads for that device
  (:class:`FeatureSpec`).

Adding an effect to a device is adding its module to the device's effect package (and a test);
nothing else changes. Adding a device means a new :class:`Device`
subclass registered in :data:`DEVICES`.

Devices live in their own packages (the AMB: :mod:`ssamb.sim`; the 1-DOF levitated ball:
:mod:`ssamb.maglev1d`) and never import close the loop; close the loop imports a device only
through :func:`get_device`.
"""
from __future__ import annotations

import functools
import importlib
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Protocol

import numpy as np

__all__ = ["Record", "Replay", "REPLAY_STREAM", "EffectModel", "EffectModule", "FeatureSpec", "Device", "DEVICES",
           "get_device", "device_names", "effect_modules", "log10_p_two_sided", "log10_p_upper"]


# -- the data ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Record:
    """Measured data ready for the analysis (device-independent container).

    Attributes
    ----------
    device : Device
        The device the data come from.
    fs_hz : float
        Sampling rate of every channel.
    channels : dict
        The device's logged channels (:attr:`Device.channels`) as float64 arrays.
    inputs : dict
        What drives a replay (the recorded references and injections), float64 arrays.
    excitation : dict
        The excitation as the data describe it (``kind`` and its parameters), normalised.
    excited_axes : tuple
        Names of the inputs (axes) whose excitation varies.
    signal : dict
        Per excited axis, the excitation signal used as the instrument of the frequency analysis.
    n_period : int or None
        Samples per period when the excitation is periodic (verified on the samples).
    lines_hz : numpy.ndarray or None
        Excited lines of a multisine.
    start : str
        How the record begins (``levitated``, ``rest``, ...; the device's replay reads it).
    settle_s : float or None
        Pre-roll of a simulated record, if the data say.
    acquisition : dict
        The logging chain (anti-alias filter) the replay applies to the model's channels too.
    device_lines_hz : tuple
        Lines the device makes whatever the excitation (e.g. a PWM carrier's aliased harmonics):
        read as features, never candidates for a line the model lacks.
    usable : tuple of (int, int)
        Sample ranges ``[a, b)`` the analysis may use (everything, or e.g. the stretches in which a
        levitated body floats); the device's record says which and why (:attr:`usable_reason`).
    usable_reason : str
        Why parts of the record are left out (empty when none is).
    meta : dict
    """

    device: object
    fs_hz: float
    channels: dict
    inputs: dict
    excitation: dict
    excited_axes: tuple
    signal: dict
    n_period: int | None
    lines_hz: np.ndarray | None
    start: str
    settle_s: float | None
    acquisition: dict = field(default_factory=dict)
    device_lines_hz: tuple = ()
    usable: tuple = ()
    usable_reason: str = ""
    meta: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        """Samples in the record."""
        return len(next(iter(self.channels.values())))

    @property
    def duration_s(self) -> float:
        return self.n / self.fs_hz


#: the noise stream of a model's replays (a key of their seed sequences besides the seed; a
#: simulated experiment or rig draws from stream 0): a replay with a simulated rig's seed would
#: otherwise repeat the rig's in-loop noise sample for sample, and a model near the truth would be
#: credited with the data's own noise (a real rig's data are never one of the model's replays)
REPLAY_STREAM = 0x5E9


@dataclass
class Replay:
    """A replay's result: the logged channels (whole record, or its first ``n`` samples) and
    whether the model's body touched a stop where it should float (``contact``)."""

    channels: dict
    contact: bool = False


# -- the effects ------------------------------------------------------------------------------
@dataclass(frozen=True)
class EffectModel:
    """A library effect with free parameters, for fitting by simulation.

    Attributes
    ----------
    name : str
    params : tuple of str
        Names of the fitted parameters (SI units in the names).
    theta0, step, lower, upper : numpy.ndarray
        Start point, finite-difference step (also the natural scale), bounds.
    build : callable
        ``theta -> list of effect specs`` that the device's replay receives.
    fixed : dict
        What the parameterisation holds fixed (e.g. the axes of a sensor effect).
    grid : tuple of numpy.ndarray
        Coarse start points to try before a local fit, for an effect whose signature gives no size
        and whose response is far from linear over its range.
    size_params : tuple of str or None
        The parameters that measure the effect's size (each 0 without the effect), for the
        test of its size against zero; None: all of them.
    mirrors : callable or None
        ``theta -> list of theta``: the points across a kink of the cost from a fitted ``theta``
        where the cost takes similar values (a delay just below a whole controller sample and
        the one as far above it), which a local fit cannot reach; each is scored after the fit and
        refitted from when it scores better (:func:`ssamb.closeloop.fit.fit_candidate`).
    aliases : callable or None
        ``theta -> list of theta``: distant points the data may not tell from a fitted ``theta``
        (a delay one whole controller sample longer or shorter, on an axis whose sensor does not
        see the PWM's ripple); scored like the mirrors, and those the fit's cost cannot be told
        from widen the reported standard errors (:func:`ssamb.closeloop.fit.alias_sd`).
    comb : callable or None
        ``theta -> list of theta``: every distant point within the effect's search range that the
        data may not tell from ``theta`` (a delay every whole controller sample longer or shorter,
        one axis at a time). The final model's spread over those neither part of the record
        rejects widens its reported standard errors (:func:`ssamb.closeloop.search._alias_spread`):
        a whole number of samples that only the phase at low lines fixes can be off by more than one.
    restart : callable or None
        ``(theta, hints) -> theta or None``: where to fit again when the fitted effect leaves its
        own signature in the residual (``hints``: the evidence the effect's module reads in that
        residual): a sensor delay's remaining phase slope added to the fitted delay. A local fit
        cannot cross the kinks of a delay's cost (:attr:`mirrors`), and one that ended on the wrong
        side of a kink leaves a phase slope the sensor path's ratio measures directly
        (:func:`ssamb.closeloop.search._restarted`).
    """

    name: str
    params: tuple
    theta0: np.ndarray
    step: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    build: Callable
    fixed: dict
    grid: tuple = ()
    size_params: tuple | None = None
    mirrors: Callable | None = None
    aliases: Callable | None = None
    comb: Callable | None = None
    restart: Callable | None = None


class EffectModule(Protocol):
    """What one effect module of a device provides (a Python module with these names).

    Attributes
    ----------
    NAME : str
        The effect's name (the binding effect names of the data formats).
    REQUIRED, OPTIONAL : tuple of str
        Its parameters.
    SIGNATURE : str
        One line: the residual it predicts.
    SEARCHABLE : bool
        Whether close the loop looks for it (``False``: a test tool, e.g. an arbitrary force).
    NEEDS_HINT : bool
        Whether a fit needs a hint from its signature (e.g. a line's frequency): such an effect
        is not fitted blind when no signature is significant.
    ORDER : int, optional
        The effect's place in the library (ties of the evidence are broken in this order; 100
        when absent, then by name).
    ALIASES : tuple of str, optional
        Library effects this one imitates exactly on some experiment, by its physics (a cross
        coupling of the gravity-loaded y fluxes is a constant x force at rest: a static load).
        Once one of them passes in a round, the other is fitted and judged too, and both are
        named when the held-out part cannot tell them apart (:meth:`Device.aliases`).
    """

    NAME: str
    REQUIRED: tuple
    OPTIONAL: tuple
    SIGNATURE: str
    SEARCHABLE: bool
    NEEDS_HINT: bool
    ORDER: int

    def validate(self, params: dict, where: str) -> dict:
        """Check the parameters (types done by the device); return them normalised."""

    def evidence(self, ft, alpha: float, settings) -> dict:
        """Evidence for the signature in the residual features ``ft``.

        ``ft`` describes the residual (measured minus model) over the fitting part, per view
        (:meth:`Device.views`), each with its noise estimated from the data:

        * ``frame``: ``fs_hz``, ``n``, ``df_hz``, ``f_hz``, ``periodic``;
        * ``offsets[v]``: ``{mean, se, z}``, the residual's mean;
        * ``windows[v]``: ``{t_s, mean, se, chi2, k}``, the residual's means over consecutive
          windows (slow trends: a response to a slowly varying reference, drift);
        * ``lines``: lines the excitation lacks, each ``{f_hz, phasor, se, chi2, views_detected}``
          (per view: complex amplitude, its standard error, chi-square with 2 dof);
        * ``excited_residual[v]``: ``{chi2, k, p, excess_ratio}`` at the excited frequencies;
        * ``ratios[path]``: per :attr:`FeatureSpec.paths` entry, the measured over the modelled
          ratio of two views at the excited frequencies, ``ln R = alpha - j 2 pi f tau``:
          ``{alpha, se_alpha, z_alpha, gain, tau_s, se_tau_s, z_tau, chi2_alpha, chi2_tau,
          n_lines, axis, path}``;
        * ``cross["a->b"]``: residual of axis b coherent with axis a's excitation beyond b's own
          response (``{view, logp, stat, kind, delta_chi2, n_views}``);
        * ``device[v]``, ``ripple[v]``: ``{chi2, k, logp}`` at the device's own lines / above
          ``ripple_min_hz`` on a periodic grid;
        * ``bands[v]``: ``{f_hz, log_ratio, se, chi2, k}``: ln of the measured over the modelled
          power spectral density in bands, with its standard error (the loop's response to its
          own noise, where no excitation is usable).

        Returns ``{score, log10_p, significant, hints, details}``: the explained chi-square,
        log10 of the Bonferroni-corrected p-value, whether it is below ``alpha``, what the
        features say of the parameters (start values), and the numbers behind the score."""

    def claim(self, ft, hints: dict, df_hz: float, settings) -> float:
        """The explained chi-square of the effect's own feature (before and after its fit)."""

    def model(self, hints: dict, record: Record, settings) -> EffectModel | str:
        """Its parameterisation for fitting, or a one-line reason why it cannot be fitted here."""

    def report(self, model: EffectModel, theta: np.ndarray, se: np.ndarray,
               significant: np.ndarray) -> list[dict]:
        """``closeloop.json`` entries (``name``, ``params``, ``uncertainty``) of a fitted effect."""


# -- the features -----------------------------------------------------------------------------
@dataclass(frozen=True)
class FeatureSpec:
    """Which device-specific features the residual analysis computes.

    Attributes
    ----------
    paths : dict
        ``name -> (axis, numerator view, denominator view)``: ratios of two views at the excited
        lines, measured over modelled (a sensor path: position over coil current).
    axis_views : dict
        ``axis -> views`` of that axis (cross-axis tests).
    counterpart : dict
        ``view -> the same view in the other axis``.
    line_views : tuple
        Views in which a line the excitation lacks is judged (e.g. the coil currents).
    ripple_views : tuple
        Views read at the device's own lines (:attr:`Record.device_lines_hz`) and above
        ``ripple_min_hz`` on a periodic grid.
    band_views : tuple
        Views whose power spectra are compared in bands (data without a usable excitation: the
        loop's response to its own noise).
    device_line_views : tuple
        Views compared in the cost at the device's own lines only (:attr:`Record.device_lines_hz`),
        not among the cost views: a digital output logged without noise whose content there is
        deterministic (the AMB's controller outputs at the PWM carrier's aliased lines, which carry
        the loop's timing). Default none.
    """

    paths: dict = field(default_factory=dict)
    axis_views: dict = field(default_factory=dict)
    counterpart: dict = field(default_factory=dict)
    line_views: tuple = ()
    ripple_views: tuple = ()
    band_views: tuple = ()
    device_line_views: tuple = ()


class Device:
    """Base class of a device (module docstring); subclasses set the attributes and methods.

    Attributes
    ----------
    name : str
    channels : tuple of str
        Logged channels compared with the model.
    view_names : tuple of str
        The views :meth:`views` returns.
    cost_views : tuple of str
        Views that enter the fit's cost.
    units : dict
        SI unit of every channel and view.
    error_groups : dict
        ``name -> channels`` whose held-out errors are also reported pooled (``currents``).
    features : FeatureSpec
    effects_package : str
        Dotted name of the package that holds the effect modules, one per effect.
    """

    name: str = ""
    channels: tuple = ()
    view_names: tuple = ()
    cost_views: tuple = ()
    units: dict = {}
    error_groups: dict = {}
    features: FeatureSpec = FeatureSpec()
    effects_package: str = ""

    # -- effects
    @property
    def effects(self) -> dict:
        """``name -> effect module`` (:class:`EffectModule`): every module of
        :attr:`effects_package` (:func:`effect_modules`)."""
        return {m.NAME: m for m in effect_modules(self.effects_package)}

    @property
    def library(self) -> tuple:
        """The effects close the loop looks for."""
        return tuple(n for n, m in self.effects.items() if m.SEARCHABLE)

    def aliases(self, name: str) -> tuple:
        """The library effects that can imitate ``name`` or that ``name`` can imitate (either
        module's ``ALIASES``), in library order."""
        lib = self.effects
        mine = set(getattr(lib[name], "ALIASES", ())) if name in lib else set()
        return tuple(n for n in self.library
                     if n != name and (n in mine or name in getattr(lib[n], "ALIASES", ())))

    def effect_model(self, name: str, hints: dict, record: Record, settings) -> EffectModel | str:
        return self.effects[name].model(hints, record, settings)

    def report_entries(self, model: EffectModel, theta, se, significant) -> list[dict]:
        return self.effects[model.name].report(model, np.asarray(theta, float), np.asarray(se, float),
                                               np.asarray(significant, bool))

    # -- data
    def unit(self, view: str) -> str:
        return self.units.get(view, "")

    def views(self, ch: Mapping) -> dict:
        """Derived views of channel arrays (measured, model or residual alike)."""
        return {v: ch[v] for v in self.view_names}

    def load(self, path) -> tuple[dict, dict]:
        """Read a data file into ``(arrays, meta)``; raise :class:`ssamb.io.DataError`."""
        raise NotImplementedError

    def validate(self, arrays: Mapping, source: str) -> None:
        """Raise :class:`ssamb.io.DataError` naming the file and column of bad data."""
        raise NotImplementedError

    def notes(self, arrays: Mapping, meta: Mapping, cfg: Mapping) -> list[str]:
        """Plausibility notes on valid but suspicious data (units off by 1000, a channel that never
        moves, ...), computed before anything is fitted."""
        return []

    def record(self, arrays: Mapping, meta: Mapping, cfg: Mapping, source: str) -> Record:
        raise NotImplementedError

    def default_config(self) -> dict:
        """The device's nominal configuration (validated)."""
        raise NotImplementedError

    def load_config(self, path=None) -> dict:
        """A configuration file of this device (default: :meth:`default_config`)."""
        raise NotImplementedError

    def priors(self, cfg: Mapping) -> dict:
        """Calibratable nominal parameters: dotted config key -> prior tolerance (relative to the
        nominal value; absolute in the key's unit when the nominal value is 0)."""
        return {}

    def floors(self, settings) -> dict:
        """Smallest noise level per view and per channel (per sample, in its unit): a channel
        logged without noise would otherwise get an infinite weight."""
        return {v: 0.0 for v in self.view_names + self.channels}

    def device_lines_hz(self, cfg: Mapping, fs_hz: float) -> tuple:
        return ()

    def replay(self, cfg: Mapping, record: Record, effects: list, n: int, seed: int | None) -> Replay:
        """The model's logged channels over the first ``n`` samples of ``record``."""
        raise NotImplementedError

    def initial_estimate(self, record: Record, cfg: Mapping) -> dict:
        """Where the calibration starts: dotted config key -> value that the data imply before any
        replay (e.g. by physical checks), for a device whose nominal model is far enough from the
        rig that a local search from it sees no gradient. The priors stay centred on the nominal
        values. Default: none (the calibration starts at the nominal values)."""
        return {}

    def calibration_bounds(self, record: Record, cfg: Mapping) -> dict:
        """Hard limits of calibrated parameters that the recording implies: dotted config key ->
        ``(lower, upper)`` in the parameter's unit (either None), e.g. a sensor's zero that would
        put a stop inside the range the body was measured in. Default: none."""
        return {}

    def checks(self, arrays: Mapping, cfg: Mapping) -> dict:
        """Physical checks of the model with configuration ``cfg`` against one recording: each a
        number computed from the data beside what the model predicts (``name -> dict``; the
        report lists them). Default: none."""
        return {}

    def measured_contact(self, record: Record, cfg: Mapping, settings) -> bool:
        """Whether the measured body touches a stop in the analysed part (a model that does is
        then not rejected for it)."""
        return False

    def physical(self, cfg: Mapping) -> str | None:
        """Why the model ``cfg`` (nominal values with calibrated overrides) is not a physical rig
        (a negative voltage drop, a scale below zero), or None. A fit treats such parameters as
        infeasible, never as a cost. Default: every configuration the calibration's bounds allow."""
        return None

    def validate_effect(self, effect: Mapping, where: str = "effect") -> dict:
        """Check one effect ``{name, <params>}`` (or ``{name, params: {...}}``); return it flat."""
        from .errors import InputError

        if not isinstance(effect, Mapping) or "name" not in effect:
            raise InputError(f"{where} {effect!r}: missing 'name'")
        name = effect["name"]
        lib = self.effects
        if name not in lib:
            raise InputError(f"{where} '{name}': unknown effect of device '{self.name}' (known: {', '.join(lib)})")
        mod = lib[name]
        flat = dict(effect.get("params", {}) or {})
        flat.update({k: v for k, v in effect.items() if k not in ("name", "params")})
        for k in mod.REQUIRED:
            if k not in flat:
                raise InputError(f"{where} '{name}': missing parameter '{k}'")
        for k in flat:
            if k not in mod.REQUIRED and k not in mod.OPTIONAL:
                raise InputError(f"{where} '{name}': unknown parameter '{k}' "
                                 f"(allowed: {', '.join(mod.REQUIRED + mod.OPTIONAL)})")
        return {"name": name, **mod.validate(flat, f"{where} '{name}'")}


def effect_modules(package: str) -> list:
    """The effect modules of a device's effect package: every module in it whose name does not
    start with an underscore, ordered by their ``ORDER`` (100 when absent) and name. Adding an
    effect to a device is adding a module there (the package is read once per process: a replay
    asks for the library every time it applies its effects)."""
    return list(_effect_modules(package))


@functools.lru_cache(maxsize=None)
def _effect_modules(package: str) -> tuple:
    import pkgutil

    pkg = importlib.import_module(package)
    mods = [importlib.import_module(f"{package}.{m.name}") for m in pkgutil.iter_modules(pkg.__path__)
            if not m.name.startswith("_")]
    return tuple(sorted(mods, key=lambda m: (getattr(m, "ORDER", 100), m.NAME)))


#: registered devices: name -> "module:Class"
DEVICES = {"amb": "ssamb.sim.device:AMB", "maglev1d": "ssamb.maglev1d.device:Maglev1D"}

_CACHE: dict = {}


def device_names() -> tuple:
    return tuple(DEVICES)


def get_device(name: str | Device = "amb") -> Device:
    """The device registered under ``name`` (a :class:`Device` is returned as is).

    Raises
    ------
    ssamb.errors.InputError
        An unknown device name (the known ones listed).
    """
    if isinstance(name, Device):
        return name
    if name not in DEVICES:
        from .errors import InputError

        raise InputError(f"device '{name}': unknown (known: {', '.join(DEVICES)})")
    if name not in _CACHE:
        mod, cls = DEVICES[name].split(":")
        _CACHE[name] = getattr(importlib.import_module(mod), cls)()
    return _CACHE[name]


# -- shared statistics of signatures --------------------------------------------------------------
def log10_p_two_sided(z: float) -> float:
    """log10 of the two-sided normal p-value of ``z``."""
    from scipy import stats

    return float(stats.norm.logsf(abs(z)) + math.log(2.0)) / math.log(10.0)


def log10_p_upper(z: float) -> float:
    """log10 of the one-sided (upper) normal p-value of ``z``."""
    from scipy import stats

    return float(stats.norm.logsf(z)) / math.log(10.0)

