r"""The peak envelope through the mismatch ETFE, extended outside the measured band
("finding a number of peaks in the ETFE and connect them with low order curves", section 5)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse


#: dB per decade of magnitude (20 log10)
_DB = 20.0


def _check_freq_mag(freqs_hz, mag, what: str = "mag") -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(freqs_hz, dtype=np.float64)
    m = np.asarray(mag, dtype=np.float64)
    if f.ndim != 1 or m.ndim != 1:
        raise ValueError(f"freqs_hz and {what} must be 1-D arrays")
    if f.size == 0:
        raise ValueError(f"the ETFE is empty: freqs_hz and {what} have no points")
    if f.size != m.size:
        raise ValueError(f"freqs_hz and {what} must have the same length, got {f.size} and {m.size}")
    if not np.all(np.isfinite(f)):
        raise ValueError("freqs_hz contains non-finite values")
    if np.any(f <= 0):
        raise ValueError("freqs_hz must be > 0 (a log-frequency fit)")
    if np.any(np.diff(f) <= 0):
        raise ValueError("freqs_hz must be strictly increasing")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{what} contains non-finite values (NaN or inf)")
    if np.any(m < 0):
        raise ValueError(f"{what} must be >= 0 (a magnitude)")
    if not np.any(m > 0):
        raise ValueError(f"{what} is identically zero: there is no mismatch to bound")
    return f, m


def _check_extension(extension: str) -> str:
    if extension not in ("hold", "smooth"):
        raise ValueError(f"extension must be 'hold' or 'smooth', got {extension!r}")
    return extension


def _to_db(m: np.ndarray) -> np.ndarray:
    floor = np.max(m) * 1e-12  # zeros become -240 dB below the largest value
    return _DB * np.log10(np.maximum(m, floor))


@dataclass(frozen=True)
class Envelope:
    r"""Smooth upper envelope of an ETFE magnitude (see :func:`peak_envelope`).

    In the measured band :math:`[f_{lo}, f_{hi}]` the envelope is the piecewise-linear
    interpolation in (:math:`\log_{10} f`, dB) of dense nodes. Outside, where nothing was
    measured, it never assumes that the mismatch shrinks:

    * where the envelope *rises* away from the band (slope :math:`S` at the edge, in dB/decade,
      pointing outwards), it continues with that slope relaxing to zero at the curvature bound
      :math:`\kappa`, :math:`E = E_{edge} + S u - \kappa u^2/2` for
      :math:`0 \le u \le S/\kappa` decades from the edge, then stays flat at
      :math:`E_{edge} + S^2/2\kappa` (the smoothest continuation a real-pole weight can follow);
    * where it *falls* away from the band it stays flat at the edge level with
      ``extension="hold"`` (the default: the level measured at the edge is assumed to persist,
      a conservative choice), or falls with the same relaxing-slope continuation (mirror image
      of the rising case) with ``extension="smooth"`` (what a low-order weight does anyway);
    * with an infinite :math:`\kappa` both sides are flat at the edge levels;
    * above the band it is multiplied by the magnitude of one real pole at ``f_rolloff_hz``,
      normalised to 1 at :math:`f_{hi}`, :math:`|1 + jf_{hi}/f_{roll}| / |1 + jf/f_{roll}|`
      (falling at 20 dB/decade above ``f_rolloff_hz``: what a strictly proper weight must do
      eventually).

    Attributes
    ----------
    nodes_hz, nodes_db : numpy.ndarray
        Nodes of the in-band curve.
    freqs_hz, mag : numpy.ndarray
        The data it bounds.
    peaks_hz : numpy.ndarray
        The data frequencies where the envelope touches the data (the "peaks" it connects).
    f_rolloff_hz : float
        Start of the high-frequency roll-off.
    max_curvature_db_per_decade2 : float
        Curvature bound used (dB/decade^2).
    extension : str
        ``"hold"`` or ``"smooth"``, see above.
    """

    nodes_hz: np.ndarray
    nodes_db: np.ndarray
    freqs_hz: np.ndarray
    mag: np.ndarray
    peaks_hz: np.ndarray
    f_rolloff_hz: float
    max_curvature_db_per_decade2: float
    extension: str = "hold"

    @property
    def f_lo_hz(self) -> float:
        return float(self.nodes_hz[0])

    @property
    def f_hi_hz(self) -> float:
        return float(self.nodes_hz[-1])

    def _edge_slopes(self) -> tuple[float, float]:
        """Outward slopes (dB/decade) at the low and high band edges (positive: rising away)."""
        xn = np.log10(self.nodes_hz)
        if xn.size < 2 or xn[-1] - xn[0] <= 0:
            return 0.0, 0.0
        s_lo = (self.nodes_db[1] - self.nodes_db[0]) / (xn[1] - xn[0])
        s_hi = (self.nodes_db[-1] - self.nodes_db[-2]) / (xn[-1] - xn[-2])
        return float(-s_lo), float(s_hi)

    def db(self, freqs_hz) -> np.ndarray:
        """Envelope in dB at ``freqs_hz`` (any positive frequencies), extension included."""
        f = np.asarray(freqs_hz, dtype=np.float64)
        x = np.log10(f)
        xn = np.log10(self.nodes_hz)
        out = np.interp(x, xn, self.nodes_db)  # flat beyond both ends
        kappa = self.max_curvature_db_per_decade2
        if math.isfinite(kappa):
            for s_out, u in zip(self._edge_slopes(), (xn[0] - x, x - xn[-1])):
                if s_out > 0 or (self.extension == "smooth" and s_out < 0):
                    sgn = 1.0 if s_out > 0 else -1.0
                    uc = np.clip(u, 0.0, abs(s_out) / kappa)
                    out = out + np.where(u > 0, s_out * uc - sgn * 0.5 * kappa * uc**2, 0.0)
        fh = np.maximum(f, self.nodes_hz[-1]) / self.f_rolloff_hz
        ref = (self.nodes_hz[-1] / self.f_rolloff_hz) ** 2
        return out - 10.0 * np.log10((1.0 + fh**2) / (1.0 + ref))

    def __call__(self, freqs_hz) -> np.ndarray:
        """Envelope magnitude (linear) at ``freqs_hz``."""
        return 10.0 ** (self.db(freqs_hz) / _DB)

    @classmethod
    def from_samples(cls, freqs_hz, envelope_mag, *, f_rolloff_hz: float | None = None,
                     max_curvature_db_per_decade2: float = 60.0, extension: str = "hold") -> "Envelope":
        """An envelope given by its values at ``freqs_hz`` (log-log interpolation between them;
        ``max_curvature_db_per_decade2`` only shapes the extension outside the band)."""
        f, m = _check_freq_mag(freqs_hz, envelope_mag, "envelope_mag")
        if np.any(m <= 0):
            raise ValueError("envelope_mag must be > 0")
        roll = 10.0 * f[-1] if f_rolloff_hz is None else float(f_rolloff_hz)
        if not roll >= f[-1]:
            raise ValueError(f"f_rolloff_hz={roll!r} must be >= the last frequency {f[-1]!r}")
        return cls(nodes_hz=f, nodes_db=_DB * np.log10(m), freqs_hz=f, mag=m, peaks_hz=f.copy(),
                   f_rolloff_hz=roll, max_curvature_db_per_decade2=float(max_curvature_db_per_decade2),
                   extension=_check_extension(extension))


def peak_envelope(
    freqs_hz,
    mag,
    *,
    max_curvature_db_per_decade2: float = 60.0,
    nodes_per_decade: int = 200,
    f_rolloff_hz: float | None = None,
    extension: str = "hold",
) -> Envelope:
    r"""Smooth upper envelope through the peaks of an ETFE magnitude (paper section 5).

    The paper finds "a number of peaks in the ETFE and connect[s] them with low order curves".
    Here the envelope :math:`E(x)` (dB, over :math:`x = \log_{10} f`) is the solution of the
    linear program

    .. math:: \min_E \int_{x_{lo}}^{x_{hi}} E(x)\,dx \quad\text{s.t.}\quad
              E(x) \ge \hat y(x), \qquad |E''(x)| \le \kappa,

    where :math:`\hat y` is the data :math:`20\log_{10} m_i` joined by straight lines in
    log-log coordinates (so :math:`E(x_i) \ge 20\log_{10} m_i` and the envelope does not sag
    between lines), on a grid of nodes that contains every data frequency (second differences
    for :math:`E''`, solved with HiGHS). The solution touches the data at a subset of points (the
    *peaks*, returned in ``peaks_hz``) and connects them with arcs of constant curvature
    :math:`\pm\kappa` or straight lines in log-log coordinates -- the "low order curves". It lies
    on or above every measured magnitude (enforced exactly at the data points).

    Why a curvature bound: a real pole or zero changes the log-magnitude slope by 20 dB/decade
    over about half a decade, with a curvature of at most :math:`10\ln 10 \approx 23`
    dB/decade^2; a weight made of real poles and zeros cannot follow sharper bends within 3 dB.
    Bridging narrow dips and widening narrow spikes to :math:`\kappa` (default 60, i.e. up to
    about three coincident real corners) makes the envelope followable by :func:`fit_weight`
    while staying as close to the data as that allows. A larger ``max_curvature`` follows the
    data more tightly and needs a higher-order weight; ``inf`` gives the piecewise-linear
    interpolation of the data.

    Outside the measured band, where the mismatch is unmeasured, the envelope never assumes it
    shrinks (``extension="hold"``): where it rises towards a band edge it continues with its edge
    slope relaxing to zero at the curvature bound :math:`\kappa` and then stays flat; where it
    falls towards an edge it stays flat at the edge level. Above the band it is multiplied by
    one real pole at ``f_rolloff_hz`` (default ten times the highest line), the roll-off a
    strictly proper weight needs. See :class:`Envelope` (and
    ``extension="smooth"``).

    Parameters
    ----------
    freqs_hz : array_like
        Strictly increasing positive frequencies (Hz) of the ETFE lines.
    mag : array_like
        Non-negative magnitudes (zeros are floored 240 dB below the largest value).
    max_curvature_db_per_decade2 : float
        :math:`\kappa` (dB/decade^2), > 0.
    nodes_per_decade : int
        Density of the grid nodes between data points.
    f_rolloff_hz : float, optional
        Start of the high-frequency roll-off (>= the highest line).
    extension : {"hold", "smooth"}
        Continuation outside the band where the envelope falls towards an edge.

    Returns
    -------
    Envelope

    Raises
    ------
    ValueError
        Empty, non-finite or negative data, non-increasing frequencies, bad parameters.
    """
    f, m = _check_freq_mag(freqs_hz, mag)
    kappa = float(max_curvature_db_per_decade2)
    if not kappa > 0:
        raise ValueError(f"max_curvature_db_per_decade2 must be > 0, got {max_curvature_db_per_decade2!r}")
    if int(nodes_per_decade) != nodes_per_decade or nodes_per_decade < 1:
        raise ValueError(f"nodes_per_decade must be an integer >= 1, got {nodes_per_decade!r}")
    roll = 10.0 * f[-1] if f_rolloff_hz is None else float(f_rolloff_hz)
    if not roll >= f[-1]:
        raise ValueError(f"f_rolloff_hz={roll!r} must be >= the highest line {f[-1]!r}")
    y = _to_db(m)
    xd = np.log10(f)
    nodes_hz, e = _envelope_nodes(f, xd, y, kappa, int(nodes_per_decade))
    at_data = np.interp(xd, np.log10(nodes_hz), e) if f.size > 1 else np.array([e[0]])
    peaks = f[at_data - y <= 1e-6 * max(1.0, float(np.max(np.abs(y))))]
    return Envelope(nodes_hz=nodes_hz, nodes_db=e, freqs_hz=f, mag=m, peaks_hz=peaks,
                    f_rolloff_hz=roll, max_curvature_db_per_decade2=kappa,
                    extension=_check_extension(extension))


def _envelope_nodes(f: np.ndarray, xd: np.ndarray, y: np.ndarray, kappa: float,
                    nodes_per_decade: int) -> tuple[np.ndarray, np.ndarray]:
    r"""Grid nodes (Hz, every data frequency among them) and the envelope on them (dB): the
    curvature-bounded LP (:func:`_envelope_lp`), or the data itself for one line or
    :math:`\kappa = \infty`."""
    if f.size == 1:
        return np.array([f[0], f[0] * (1 + 1e-12)]), np.array([y[0], y[0]])
    if not math.isfinite(kappa):
        nodes_x, e = xd, y.copy()
    else:
        h_max = 1.0 / float(nodes_per_decade)
        pieces = [xd[:1]]
        for a, b in zip(xd[:-1], xd[1:]):
            k = max(1, int(math.ceil((b - a) / h_max)))
            pieces.append(np.linspace(a, b, k + 1)[1:])
        nodes_x = np.concatenate(pieces)
        data_idx = np.searchsorted(nodes_x, xd)
        e = _envelope_lp(nodes_x, data_idx, y, kappa)
        e[data_idx] = np.maximum(e[data_idx], y)  # exactly on or above the data
    nodes_hz = 10.0 ** nodes_x
    nodes_hz[0], nodes_hz[-1] = f[0], f[-1]
    return nodes_hz, e


def _envelope_lp(x: np.ndarray, data_idx: np.ndarray, y: np.ndarray, kappa: float) -> np.ndarray:
    n = x.size
    h = np.diff(x)
    # trapezoid weights of the integral
    w = np.zeros(n)
    w[:-1] += h / 2
    w[1:] += h / 2
    rows, cols, vals = [], [], []
    b = []
    r = 0
    # data: -E_k <= -y(x_k), y interpolated linearly (log-log) between the data points, so the
    # envelope does not sag between lines (at the data points this is E_i >= y_i)
    y_nodes = np.interp(x, x[data_idx], y)
    for k in range(n):
        rows.append(r)
        cols.append(k)
        vals.append(-1.0)
        b.append(-y_nodes[k])
        r += 1
    # curvature: |(E_{k+1}-E_k)/h_k - (E_k-E_{k-1})/h_{k-1}| <= kappa (h_{k-1}+h_k)/2
    for k in range(1, n - 1):
        c_m, c_0, c_p = 1.0 / h[k - 1], -(1.0 / h[k - 1] + 1.0 / h[k]), 1.0 / h[k]
        lim = kappa * (h[k - 1] + h[k]) / 2.0
        for sgn in (1.0, -1.0):
            rows += [r, r, r]
            cols += [k - 1, k, k + 1]
            vals += [sgn * c_m, sgn * c_0, sgn * c_p]
            b.append(lim)
            r += 1
    a_ub = scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(r, n))
    # shift the data to O(1) numbers for the solver
    y0 = float(np.max(y))
    b = np.asarray(b)
    b[:n] += y0
    res = scipy.optimize.linprog(w, A_ub=a_ub, b_ub=b, bounds=[(None, None)] * n, method="highs")
    if res.status != 0:  # pragma: no cover - the LP is always feasible and bounded
        raise RuntimeError(f"envelope LP failed: {res.message}")
    return res.x + y0
