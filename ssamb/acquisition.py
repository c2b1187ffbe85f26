r"""The logging chain of a rig: an anti-alias low-pass on the logged analog channels.

A rig's data logger samples the position probes and the current transducers through its own
anti-alias filter; the DSP's digital values (the self-sensing estimate, the controller outputs,
the references and injections) reach the log as numbers and pass no filter. The simulated rig
(:mod:`ssamb.rig`, scenario key ``acquisition``) applies the filter to its logged channels, and a
replay of the model applies the same function to the model's channels, so that model and data
pass the same chain.

Specification (a mapping; ``None`` or ``{}``: no filter)::

    acquisition: {antialias_hz: 10000.0, order: 4}

``antialias_hz`` is the -3 dB cutoff :math:`f_c` (0 < f_c < f_s/2), ``order`` the Butterworth
order :math:`n` (an integer 1-8, default 4). The filtered channels are :data:`ANALOG_CHANNELS`.

The filter
----------
An analog Butterworth low-pass has

.. math::

    |H_a(j 2\pi f)|^2 = \frac{1}{1 + (f/f_c)^{2n}}, \qquad
    H_a(s) = \prod_{k=1}^{n} \frac{1}{s/\omega_c - p_k}, \quad
    p_k = e^{\,j\pi (2k + n - 1)/(2n)} .

It is simulated at the controller rate :math:`f_s` as its bilinear (Tustin) discretisation with
the cutoff prewarped (:func:`scipy.signal.butter`), causal, as second-order sections
(:func:`scipy.signal.sosfilt`). Its response is the analog one at the warped frequency,

.. math::

    H(e^{j 2\pi f/f_s}) = H_a\!\left(j\,\omega_c \frac{\tan(\pi f/f_s)}{\tan(\pi f_c/f_s)}\right),

exact at :math:`f_c` (-3 dB, phase :math:`-n\cdot 45°`). For :math:`f_c \le f_s/8` the gain is
within 1 % of the analog one up to :math:`f_c/2`, and the low-frequency phase lag (the delay
:math:`\tau_0 = 1/(\omega_c \sin(\pi/2n))`) is the analog one times
:math:`(\pi f_c/f_s)/\tan(\pi f_c/f_s)`: 39.6 instead of 41.6 µs for 10 kHz, order 4 at
83.3 kHz. A replay passes the same digital filter, so model and data agree.

The filter state starts at the steady state of the first sample (:func:`scipy.signal.sosfilt_zi`
times it), so a record starts without a filter transient. The function is pure and
deterministic.
"""
from __future__ import annotations

import functools
import math
import numbers
from typing import Any, Mapping

import numpy as np

from .errors import InputError

__all__ = ["ANALOG_CHANNELS", "ACQUISITION_KEYS", "DEFAULT_ORDER", "validate_acquisition", "apply_acquisition"]

#: logged analog channels that pass the anti-alias filter (the DSP's digital values do not)
ANALOG_CHANNELS = ("x_meas", "y_meas", "i_ypos", "i_yneg", "i_xpos", "i_xneg")
#: keys of an acquisition specification
ACQUISITION_KEYS = ("antialias_hz", "order")
#: Butterworth order when the specification gives none
DEFAULT_ORDER = 4
_MAX_ORDER = 8


def validate_acquisition(spec: Any, where: str, fs_hz: float | None = None, *,
                         key: str = "acquisition", error: type[InputError] = InputError) -> dict:
    """Check an acquisition specification; return it normalised (``{}``: no filter).

    Parameters
    ----------
    spec : mapping or None
        ``{antialias_hz, order}`` (module docstring); ``None`` or ``{}`` means no filter.
    where : str
        The file (or caller) the specification comes from, first in every message.
    fs_hz : float, optional
        The sampling rate; when given, ``antialias_hz`` must lie below ``fs_hz / 2``.
    key : str
        The specification's own key in that file (``acquisition``; ``meta.acquisition`` in a
        data file's sidecar).
    error : type
        The :class:`~ssamb.errors.InputError` subclass to raise.

    Returns
    -------
    dict
        ``{"antialias_hz": float, "order": int}``, or ``{}``.

    Raises
    ------
    InputError
        One line ``"{where}: key '{key}.K': ..."`` naming the offending key.
    """
    if spec is None:
        return {}
    if not isinstance(spec, Mapping):
        raise error(f"{where}: key '{key}': must be a mapping with {', '.join(ACQUISITION_KEYS)} (got {spec!r})")
    unknown = [k for k in spec if k not in ACQUISITION_KEYS]
    if unknown:
        raise error(f"{where}: key '{key}.{unknown[0]}': unknown (allowed: {', '.join(ACQUISITION_KEYS)})")
    if not spec:
        return {}
    if "antialias_hz" not in spec:
        raise error(f"{where}: key '{key}.antialias_hz': missing (required)")
    fc = spec["antialias_hz"]
    if isinstance(fc, bool) or not isinstance(fc, numbers.Real) or not math.isfinite(float(fc)) or fc <= 0:
        raise error(f"{where}: key '{key}.antialias_hz': must be a finite number > 0 (got {fc!r})")
    if fs_hz is not None and not float(fc) < float(fs_hz) / 2:
        raise error(f"{where}: key '{key}.antialias_hz': must lie below the Nyquist frequency "
                    f"{float(fs_hz) / 2} Hz (got {fc!r})")
    order = spec.get("order", DEFAULT_ORDER)
    if isinstance(order, bool) or not isinstance(order, numbers.Integral) or not 1 <= int(order) <= _MAX_ORDER:
        raise error(f"{where}: key '{key}.order': must be an integer 1-{_MAX_ORDER} (got {order!r})")
    return {"antialias_hz": float(fc), "order": int(order)}


def apply_acquisition(channels: Mapping[str, np.ndarray], acquisition: Mapping | None, fs_hz: float) -> dict:
    """The channels as the logging chain delivers them: :data:`ANALOG_CHANNELS` low-passed.

    Parameters
    ----------
    channels : mapping of str to 1-D array
        Signals sampled at ``fs_hz`` (any subset of the measured-data columns, and others).
    acquisition : mapping or None
        The specification (module docstring); ``None`` or ``{}``: no filter.
    fs_hz : float
        Sampling rate of the channels (the controller rate).

    Returns
    -------
    dict
        A new dict: the analog channels present in ``channels`` filtered (new float arrays,
        :math:`y = H(z)\\,x` from the steady state of :math:`x_0`), every other entry the
        caller's own object, unchanged.
    """
    from scipy.signal import sosfilt

    spec = validate_acquisition(acquisition, "apply_acquisition", fs_hz)
    out = dict(channels)
    if not spec:
        return out
    sos, zi_unit = _design(spec["order"], spec["antialias_hz"], float(fs_hz))
    for name in ANALOG_CHANNELS:
        if name not in channels:
            continue
        x = np.asarray(channels[name], dtype=float)
        out[name] = sosfilt(sos, x, zi=zi_unit * x[0])[0] if x.size else x.copy()
    return out


@functools.lru_cache(maxsize=8)
def _design(order: int, antialias_hz: float, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The Butterworth low-pass's second-order sections and its unit-step steady state (shared
    between calls: read only)."""
    from scipy.signal import butter, sosfilt_zi

    sos = butter(order, antialias_hz, btype="lowpass", fs=fs_hz, output="sos")
    return sos, sosfilt_zi(sos)
