r"""Additive dynamic uncertainty: ETFE of the mismatch (eq. 6), peak envelope, weight fit (Fig. 7).

Paper section 5 models what the nominal LTI model misses as an
additive uncertainty :math:`G = \bar G + W\Delta`, :math:`\|\Delta\|_\infty \le 1` (eq. 4), and
measures its size with the empirical transfer function estimate (ETFE) of eq. (6):

.. math:: |W(j\omega)| \;\ge\; \left|\frac{Y(j\omega)}{X(j\omega)} -
          \frac{\bar Y(j\omega)}{\bar X(j\omega)}\right|,

where :math:`X, Y` are the input and output spectra of one subsystem inside the nonlinear
("real") closed loop and :math:`\bar X, \bar Y` the same signals in the closed-loop LTI model,
both driven at the system input by the same random-phase multisine reference (5-26 Hz,
100 um). The steps here are

1. :func:`line_spectra` -- DFT of each steady-state period at the excited lines, averaged, with
   the period-to-period variance as a noise estimate;
2. :func:`etfe` and :func:`additive_mismatch` -- :math:`Y/X`, and
   :math:`Y/X - \bar Y/\bar X` with a per-line standard deviation;
3. :func:`peak_envelope` -- a smooth upper envelope through the peaks of :math:`|Y/X - \bar
   Y/\bar X|` ("finding a number of peaks in the ETFE and connect them with low order curves");
4. :func:`fit_weight` -- a stable, minimum-phase, strictly proper :math:`W(s)` with real poles
   and zeros placed by first-order asymptotic Bode approximations and refined, within
   ``tol_db`` (3 dB in the paper) of the envelope on the measured band and above the ETFE on
   every line;
5. :func:`ssamb.figures.plot_weight` -- the Fig. 7 equivalent.

Modules: :mod:`.etfe` (steps 1-2), :mod:`.envelope` (3), :mod:`.weight` (4); the stage that
drives them is :mod:`ssamb.stages.uncertainty`.

Conventions: frequencies in Hz (``freqs_hz``), :math:`s = j 2\pi f` in rad/s for the transfer
functions, magnitudes in the unit of the mismatch (output unit per input unit, e.g. m/A for the
self-sensing module whose input is a coil current and output a position estimate), dB is
:math:`20\log_{10}`.
"""
from __future__ import annotations

import numpy as np

from .envelope import Envelope, peak_envelope
from .etfe import Etfe, LineSpectra, Mismatch, additive_mismatch, etfe, line_spectra
from .weight import WeightFit, fit_weight, weight_db

__all__ = [
    "LineSpectra", "Etfe", "Mismatch", "Envelope", "WeightFit", "line_spectra", "etfe",
    "additive_mismatch", "peak_envelope", "fit_weight", "weight_db", "measure_weight",
]


def measure_weight(u_real, y_real, u_model, y_model, *, fs_hz: float, samples_per_period: int, lines_bins,
                   n_transient_periods: int, k_sigma: float, max_curvature_db_per_decade2: float,
                   tol_db: float, max_order: int) -> tuple[Mismatch, np.ndarray, WeightFit]:
    r"""Steps 2-4 for one channel pair: the additive mismatch ETFE (eq. (6)) on the excited
    lines, the envelope target :math:`|\hat G - \bar G| + k_\sigma\,\sigma` (so that noise cannot
    lift a line above W), its peak envelope and the weight fitted within ``tol_db``.

    The four signals are whole periods of the same periodic excitation in the nonlinear ("real")
    loop and in the LTI loop. Returns ``(mismatch, target, fit)``.
    """
    mm = additive_mismatch(u_real, y_real, u_model, y_model, fs_hz=fs_hz, samples_per_period=samples_per_period,
                           lines_bins=lines_bins, n_transient_periods=int(n_transient_periods))
    k_sigma = float(k_sigma)
    target = mm.upper(k_sigma) if k_sigma > 0 else mm.mag
    env = peak_envelope(mm.freqs_hz, target, max_curvature_db_per_decade2=float(max_curvature_db_per_decade2))
    fit = fit_weight(mm.freqs_hz, env, target, tol_db=float(tol_db), max_order=int(max_order))
    return mm, target, fit
