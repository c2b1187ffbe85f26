r"""The split of a record into a fitting part and a held-out part.

The record itself (:class:`ssamb.device.Record`) is the device's: its channels, the excitation that
drives the replay, what ``meta`` says about it. The split (:class:`Split`) discards a start-up
interval, then cuts the rest into a fitting part and a held-out part. When the excitation is
periodic (``Record.n_period``), the cut points fall on whole periods, so that both parts are
leakage-free for the DFT at the excited lines.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..device import Record
from ..io import DataError

__all__ = ["Record", "Split", "make_split", "usable_range"]


@dataclass(frozen=True)
class Split:
    """Sample ranges of the analysis.

    ``[i0, i_fit)`` is the fitting part and ``[i_fit, i_end)`` the held-out part (``i0`` after
    the discarded start-up). With a periodic excitation all boundaries are whole periods
    (``n_period``) counted from the start of the record.
    """

    i0: int
    i_fit: int
    i_end: int
    n_period: int | None

    @property
    def fit(self) -> slice:
        return slice(self.i0, self.i_fit)

    @property
    def hold(self) -> slice:
        return slice(self.i_fit, self.i_end)

    @property
    def fit_fraction(self) -> float:
        return (self.i_fit - self.i0) / (self.i_end - self.i0)


def usable_range(rec: Record) -> tuple[int, int]:
    """The longest of the record's usable sample ranges (:attr:`ssamb.device.Record.usable`; the
    whole record when it names none)."""
    ranges = [(int(a), int(b)) for a, b in (rec.usable or ()) if b > a]
    if not ranges:
        return 0, rec.n
    return max(ranges, key=lambda r: (r[1] - r[0], -r[0]))


def make_split(rec: Record, fit_fraction: float, discard_s: float, min_fit_s: float,
               min_holdout_s: float, source: str = "data") -> Split:
    """Split a record; periodic excitations are cut on whole periods (at least 2 fit, 1 held out).

    The split lies in the longest usable range of the record (:func:`usable_range`), after
    ``discard_s`` of start-up counted from the record's start.

    Raises
    ------
    DataError
        The record is too short to give a fitting part of ``min_fit_s`` and a held-out part of
        ``min_holdout_s`` after discarding ``discard_s`` of start-up.
    """
    fs = rec.fs_hz
    a, n = usable_range(rec)
    need = discard_s + min_fit_s + min_holdout_s
    where = ("" if (a, n) == (0, rec.n)
             else f" in its longest usable stretch ({a / fs:.4g}-{n / fs:.4g} s: {rec.usable_reason})")
    too_short = DataError(
        f"{source}: too short to split: {(n - a) / fs:.4g} s of data{where}; the analysis discards {discard_s:g} s of "
        f"start-up and needs at least {min_fit_s:g} s to fit and {min_holdout_s:g} s held out "
        f"({need:g} s in all)")
    p = rec.n_period
    start = max(discard_s * fs, a)
    if p is not None:
        k0 = math.ceil(start / p - 1e-9)
        n_per = n // p - k0
        k_fit = int(round(fit_fraction * n_per))
        # at least 2 periods on each side when possible (off-grid noise bins need 2 periods)
        k_fit = min(max(k_fit, 2), n_per - (2 if n_per >= 4 else 1))
        if n_per >= 3 and k_fit * p >= min_fit_s * fs and (n_per - k_fit) * p >= min_holdout_s * fs:
            return Split(i0=k0 * p, i_fit=(k0 + k_fit) * p, i_end=(k0 + n_per) * p, n_period=p)
    i0 = int(math.ceil(start))
    rest = n - i0
    i_fit = i0 + int(round(fit_fraction * rest))
    if rest <= 0 or (i_fit - i0) < min_fit_s * fs or (n - i_fit) < min_holdout_s * fs:
        raise too_short
    return Split(i0=i0, i_fit=i_fit, i_end=n, n_period=None)
