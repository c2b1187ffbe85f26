r"""The computed cause of a μ peak (paper section 6.2, Fig. 8).

The paper reads its μ plot as "dominated by an extreme sensitivity for the critical frequency
of the AMB plant" (~2 Hz). A μ peak at :math:`f^*` can come from three places, and
:func:`peak_cause` computes the evidence for each:

1. **a lightly damped closed-loop pole** near :math:`f^*`. The loop is discrete (dt = T); each
   pole :math:`z_i` maps to :math:`s_i = \ln z_i / T` (exact for the sampled modes), natural
   frequency :math:`f_i = |s_i|/2\pi` and damping ratio :math:`\zeta_i = -\mathrm{Re}\,s_i/|s_i|`.
   With :math:`A = V\Lambda V^{-1}` the uncertainty channels decompose into modal terms,

   .. math:: N_{11}(f) = W(j2\pi f)\Big(\sum_i \frac{(C v_i)(w_i^T B)}{e^{j2\pi fT} - z_i} + D\Big),

   and the *share* of a mode (with its conjugate) is :math:`\bar\sigma` of its term over
   :math:`\bar\sigma(N_{11})` at :math:`f^*`. Shares mislead when terms cancel (near DC they
   often exceed 1), so the attribution uses a local counterfactual instead: each mode alone is
   damped, :math:`s_i' = s_i - \Delta\zeta\,|s_i|`, with its static gain kept, and the relative
   drop of μ at :math:`f^*` is its *sensitivity*; the most sensitive mode is the dominant one,
   and the whole μ curve is recomputed with it damped;
2. **a feature of the weight**: :math:`|W|` at :math:`f^*`, its corners (zeros and poles, Hz)
   and where :math:`|W|` is largest; the counterfactual replaces :math:`W` by the constant
   :math:`|W(j2\pi f^*)|` and recomputes: if the peak stays at :math:`f^*`, the loop shapes it,
   if it moves, the weight does;
3. **a plant mode**: the identified plant's poles in the same map, in particular its unstable
   pole :math:`s = +\sqrt{k_s/m}` (the critical frequency :math:`\sqrt{k_s/m}/2\pi`);
4. **a near-cancellation**: the zeros of the self-sensing model (its transfer from its input
   to ``y_ss``) in the same map. A zero next to a loop pole (the PID's integrator at
   :math:`z = 1`, a slow plant or amplifier pole) leaves a slow closed-loop pole beside it that
   the loop barely controls -- the signature of a model that must map a large operating point
   (3.6 A of bias current) onto about 0 m without an offset term.

The verdict (:func:`peak_cause` ``cause``) follows written rules: "closed-loop pole" when the
dominant mode lies within :data:`NEAR_FACTOR` of :math:`f^*` and damping it lowers μ there by
at least :data:`DOMINANT_DROP` -- "near-cancellation" when, besides, a zero of the self-sensing
model lies within :data:`NEAR_FACTOR` of that mode; otherwise "weight" when the flat-weight
peak moves by more than :data:`NEAR_FACTOR`; otherwise "loop gain (no single mode)". A peak at an end of the grid is
flagged (``at_grid_edge``). Every number behind the verdict is returned, so a report can show
the computation rather than assert it.
"""
from __future__ import annotations

import warnings
from typing import Mapping, Sequence

import control
import numpy as np

__all__ = ["discrete_modes", "modal_terms", "weight_features", "peak_cause", "sensor_zeros"]

#: a mode "sits at" the peak when its natural frequency is within this factor of f*
NEAR_FACTOR = 1.5
#: damping added to one mode at a time (s' = s - DZETA |s|) to measure mu's sensitivity to it
DZETA = 0.1
#: a mode "causes" the peak when that damping lowers mu at f* by at least this fraction (for a
#: resonance of damping zeta the drop is about DZETA / (zeta + DZETA): 10 % up to zeta = 0.9)
DOMINANT_DROP = 0.1


def discrete_modes(poles_z, dt: float) -> list[dict]:
    r"""Continuous equivalents of discrete poles, one per conjugate pair, least damped first.

    :math:`s = \ln z / T`; ``f_hz`` = :math:`|s|/2\pi` (natural), ``fd_hz`` =
    :math:`|\mathrm{Im}\,s|/2\pi` (damped), ``zeta`` = :math:`-\mathrm{Re}\,s/|s|` (negative:
    unstable; 1: real stable pole). A pole at z = 0 (a pure delay) is skipped.
    """
    out = []
    for z in np.asarray(poles_z, complex).ravel():
        if z.imag < -1e-12 * max(1.0, abs(z)) or abs(z) == 0:
            continue
        s = np.log(z) / dt
        wn = abs(s)
        out.append({"z": [float(z.real), float(z.imag)], "s": [float(s.real), float(s.imag)],
                    "f_hz": float(wn / (2 * np.pi)), "fd_hz": float(abs(s.imag) / (2 * np.pi)),
                    "zeta": float(-s.real / wn) if wn > 0 else 1.0, "abs_z": float(abs(z))})
    out.sort(key=lambda m: m["zeta"])
    return out


def modal_terms(sys: control.StateSpace, rows: Sequence[int], cols: Sequence[int]):
    r"""Modal decomposition of a discrete system's channels ``rows x cols``.

    Returns ``(poles, residues, D, cond)``: :math:`z_i`, :math:`R_i = (C v_i)(w_i^T B)` (each
    ``len(rows) x len(cols)``), the feedthrough and the condition number of :math:`V` (large:
    nearly defective, shares less reliable).
    """
    A = np.asarray(sys.A, float)
    B = np.asarray(sys.B, float)[:, list(cols)]
    C = np.asarray(sys.C, float)[list(rows)]
    D = np.asarray(sys.D, float)[np.ix_(list(rows), list(cols))]
    lam, V = np.linalg.eig(A)
    lam = lam.astype(complex)
    W = np.linalg.inv(V)
    res = np.einsum("ri,ic->irc", C @ V, W @ B).astype(complex)
    return lam, res, D, float(np.linalg.cond(V))


def weight_features(weight: control.TransferFunction, f_peak_hz: float, freqs_hz) -> dict:
    """The weight at the peak (:math:`|W|`), its corners (Hz) and where :math:`|W|` is largest on the grid."""
    f = np.asarray(freqs_hz, float)
    mag = np.abs(np.squeeze(weight(2j * np.pi * f)))
    z = np.abs(np.atleast_1d(weight.zeros())) / (2 * np.pi)
    p = np.abs(np.atleast_1d(weight.poles())) / (2 * np.pi)
    corners = sorted([("zero", float(x)) for x in z] + [("pole", float(x)) for x in p], key=lambda c: c[1])
    near = min(corners, key=lambda c: abs(np.log(c[1] / f_peak_hz))) if corners else None
    k = int(np.argmax(mag))
    return {"mag_at_peak": float(np.abs(np.squeeze(weight(2j * np.pi * f_peak_hz)))),
            "max_mag": float(mag[k]), "max_mag_hz": float(f[k]),
            "corners_hz": [{"kind": c[0], "f_hz": c[1]} for c in corners],
            "nearest_corner": None if near is None else {"kind": near[0], "f_hz": near[1]}}


def _pairs(lam: np.ndarray, dt: float) -> list[np.ndarray]:
    """Indices of each pole with its conjugate (one group per real pole or pair)."""
    used, groups = set(), []
    for i, z in enumerate(lam):
        if i in used:
            continue
        g = [i]
        if abs(z.imag) > 1e-12 * max(1.0, abs(z)):
            j = int(np.argmin(np.abs(lam - np.conj(z)) + np.where(np.arange(len(lam)) == i, np.inf, 0)))
            g.append(j)
        used.update(g)
        groups.append(np.array(g))
    return groups


def _n11_modal(lam, res, D, dt, wfun, drop=()):
    """Callable f -> N11 from the modal terms, without the poles in ``drop``."""
    keep = np.setdiff1d(np.arange(len(lam)), np.asarray(drop, int))

    def f(hz):
        z = np.exp(2j * np.pi * hz * dt)
        T = D + np.tensordot(1.0 / (z - lam[keep]), res[keep], axes=1)
        return wfun(hz)[:, None] * T

    return f


def _sigma(M) -> float:
    return float(np.linalg.norm(np.atleast_2d(M), 2))


def _damped(lam: np.ndarray, res: np.ndarray, g, dt: float, dzeta: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Poles and residues with group ``g`` damped and its static gain kept.

    :math:`s' = s - \Delta\zeta\,|s|` (a complex pair's damping ratio rises by about
    :math:`\Delta\zeta`, a real pole becomes that much faster), :math:`z' = e^{s'T}`, and
    :math:`R' = R\,(1 - z')/(1 - z)` so that the mode's DC contribution :math:`R/(1 - z)` is
    unchanged: the counterfactual changes the dynamics of one mode, not the statics of the loop.
    """
    lam2, res2 = lam.copy(), res.copy()
    s = np.log(lam[g]) / dt
    lam2[g] = np.exp((s - dzeta * np.abs(s)) * dt)
    den = 1 - lam[g]
    ratio = np.where(np.abs(den) > 1e-12, (1 - lam2[g]) / np.where(np.abs(den) > 1e-12, den, 1.0), 1.0)
    res2[g] = res[g] * ratio[:, None, None]
    return lam2, res2


def _mode_effects(lam, res, D, dt, wfun, f_hz, blk, dzeta) -> list[dict]:
    """Every mode (conjugates together) with its share of sigma_max(N11) at ``f_hz`` and the
    relative drop of mu at ``f_hz`` when it alone is damped by ``dzeta`` (least damped first)."""
    from .mu import mussv

    z = np.exp(2j * np.pi * f_hz * dt)
    wv = wfun(f_hz)[:, None]
    N = wv * (D + np.tensordot(1.0 / (z - lam), res, axes=1))
    total, mu0 = _sigma(N), mussv(N, blk).upper
    out = []
    for g in _pairs(lam, dt):
        m = discrete_modes(lam[g[:1]] if lam[g[0]].imag >= 0 else lam[g[-1:]], dt)
        if not m:
            continue
        term = wv * np.tensordot(1.0 / (z - lam[g]), res[g], axes=1)
        lam2, res2 = _damped(lam, res, g, dt, dzeta)
        mu1 = mussv(wv * (D + np.tensordot(1.0 / (z - lam2), res2, axes=1)), blk).upper
        out.append({**m[0], "share": _sigma(term) / total if total > 0 else 0.0,
                    "mu_drop": (mu0 - mu1) / mu0 if mu0 > 0 else 0.0, "index": g.tolist()})
    out.sort(key=lambda m: m["zeta"])
    return out


def _near(f: float, f0: float) -> bool:
    return f > 0 and f0 > 0 and abs(np.log(f / f0)) <= np.log(NEAR_FACTOR)


def sensor_zeros(selfsensing, dt: float) -> tuple[list[dict], float]:
    """Zeros of the self-sensing model (its input -> ``y_ss``, the affine column left out) as
    :func:`discrete_modes` (each with ``abs_z``), and its static gain
    :math:`c (I - A)^{-1} b + d`."""
    ins = list(selfsensing.all_input_names)
    j = next(i for i, n in enumerate(ins) if n != "one")
    A, b = np.asarray(selfsensing.A, float), np.asarray(selfsensing.B, float)[:, [j]]
    c, d = np.asarray(selfsensing.C, float)[[0]], np.asarray(selfsensing.D, float)[[0]][:, [j]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        z = control.zeros(control.ss(A, b, c, d, dt))
    dc = float((c @ np.linalg.solve(np.eye(len(A)) - A, b) + d)[0, 0])
    return discrete_modes(z, dt), dc


def _verdict(a: dict, edge, plant_crit) -> tuple[str, str]:
    """Primary cause and the report sentence of one attribution (rules in the module docstring)."""
    f_pk, dom, damped, flat_hz = a["peak_hz"], a["dominant"], a["damped_dominant"], a["flat_weight"]["peak_hz"]
    near = lambda f: _near(f, f_pk)  # noqa: E731
    mode_cause = dom["mu_drop"] >= DOMINANT_DROP and near(dom["f_hz"])
    weight_cause = not near(flat_hz)
    zeros = a.get("sensor_zeros") or []
    cancel = [z for z in zeros if _near(z["f_hz"], dom["f_hz"])] if mode_cause else []
    cause = ("near-cancellation" if cancel else "closed-loop pole" if mode_cause else "weight" if weight_cause
             else "loop gain (no single mode)")
    where = {"low": " (the grid's lowest frequency: mu rises towards DC)",
             "high": " (the grid's highest frequency)"}.get(edge, "")
    pole = (f"{dom['f_hz']:.3g} Hz, zeta {dom['zeta']:.2g} (damping it by {DZETA:g} lowers mu there by "
            f"{dom['mu_drop']:.0%}; the peak becomes {damped['peak']:.3g} at {damped['peak_hz']:.3g} Hz)")
    text = f"mu peak {a['peak']:.3g} at {f_pk:.3g} Hz{where}: "
    text += f"closed-loop pole at {pole}" if mode_cause else \
        f"no single closed-loop pole sets it (most sensitive: {pole})"
    text += (f"; there |W| = {a['weight_mag']:.3g} and the unweighted transfer {a['loop_gain_at_peak']:.3g}; "
             f"with a flat weight the peak is at {flat_hz:.3g} Hz")
    if cancel:
        z = cancel[0]
        text += (f"; the self-sensing model has a zero at {z['f_hz']:.3g} Hz (|z| = {z['abs_z']:.6f}) next to that "
                 f"pole: a near-cancellation (its static gain {a.get('sensor_dc_gain', float('nan')):.3g})")
    elif any(near(z["f_hz"]) for z in zeros):
        z = next(z for z in zeros if near(z["f_hz"]))
        text += f"; the self-sensing model has a zero at {z['f_hz']:.3g} Hz"
    if plant_crit is not None:
        text += ("; the identified plant model's unstable pole (the critical frequency sqrt(ks/m)/2pi) is at "
                 f"{plant_crit:.3g} Hz")
    return cause, text + f"; cause: {cause}"


def _attribute(loop, weights, case: str, f_pk: float, peak: float, grid, modal) -> dict:
    """Modes with their mu sensitivity at ``f_pk``, the dominant one, the mu curve with it damped
    and the mu curve with a flat weight (see :func:`peak_cause`)."""
    from .generalized_plant import case_structure, n11_channels, n11_function
    from .robustness import mu_frequency_response

    lam, res, D, dt, wfun = modal
    blk, wrow = case_structure(case), n11_channels(loop, case)[2]
    modes = _mode_effects(lam, res, D, dt, wfun, f_pk, blk, DZETA)
    dom = max(modes, key=lambda m: m["mu_drop"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dm = mu_frequency_response(_n11_modal(*_damped(lam, res, dom["index"], dt, DZETA), D, dt, wfun), grid, blk)
        # in a fixed order: reproducible files
        flat = {k: abs(complex(np.squeeze(weights[k](2j * np.pi * f_pk)))) for k in dict.fromkeys(wrow)}
        fl = mu_frequency_response(n11_function(loop, {k: control.tf([v], [1]) for k, v in flat.items()}, case),
                                   grid, blk)
    strip = lambda m: {k: v for k, v in m.items() if k != "index"}  # noqa: E731
    exact = n11_function(loop, weights, case)(f_pk)
    return {"peak": float(peak), "peak_hz": float(f_pk), "modes": modes, "dominant": strip(dom),
            "most_sensitive": [strip(m) for m in sorted(modes, key=lambda m: -m["mu_drop"])[:5]],
            "damped_dominant": {"peak": dm.peak, "peak_hz": dm.peak_hz},
            "flat_weight": {"peak": fl.peak, "peak_hz": fl.peak_hz, "mag": flat},
            "weight_mag": float(max(flat.values())),
            "loop_gain_at_peak": _sigma(exact / wfun(f_pk)[:, None])}


def _interior_max(sweep) -> tuple[float, float] | None:
    """The largest local maximum of the mu curve at least :data:`NEAR_FACTOR` away from the
    grid's ends (the refinement crowds points next to an end peak), if any."""
    u, f = np.asarray(sweep.upper), np.asarray(sweep.freqs_hz)
    lo, hi = f.min() * NEAR_FACTOR, f.max() / NEAR_FACTOR
    idx = [i for i in range(1, len(u) - 1)
           if lo < f[i] < hi and u[i] > u[i - 1] and u[i] >= u[i + 1]]
    if not idx:
        return None
    i = max(idx, key=lambda j: u[j])
    return float(f[i]), float(u[i])


def peak_cause(loop: control.StateSpace, weights: Mapping, case: str, sweep, plant=None,
               n_modes: int = 5, selfsensing=None) -> dict:
    r"""The computed cause of the μ peak of one uncertainty case.

    Parameters
    ----------
    loop : control.StateSpace
        :func:`ssamb.generalized_plant.uncertainty_loop` (discrete).
    weights : mapping
        subsystem -> continuous weight :math:`W(s)` (those of the case).
    case : str
        The uncertainty case (:data:`ssamb.generalized_plant.CASES`).
    sweep : ssamb.robustness.MuSweep
        The μ curve of the case (its grid is reused for the counterfactuals).
    plant : IdentifiedModel, optional
        The plant model whose poles (and unstable pole, the critical frequency) are reported.
    n_modes : int
        Least-damped closed-loop modes listed.
    selfsensing : IdentifiedModel, optional
        The self-sensing model whose zeros (:func:`sensor_zeros`) are checked for a
        near-cancellation with the dominant closed-loop pole.

    Returns
    -------
    dict
        ``peak``, ``peak_hz``, ``at_grid_edge`` (None, 'low' or 'high'); ``least_damped``
        (closed-loop modes in the grid's band: ``f_hz``, ``zeta``, ``z``, ``s``, ``mu_drop`` =
        relative drop of μ at the peak when the mode alone is damped by :data:`DZETA`,
        ``share`` = its term's share of :math:`\bar\sigma(N_{11})`, which can exceed 1 when
        terms cancel); ``most_sensitive``; ``dominant`` (largest ``mu_drop``);
        ``damped_dominant`` (μ peak and frequency with it damped); ``flat_weight`` (μ peak
        with :math:`W \equiv |W(j2\pi f^*)|`); ``weight_mag`` and ``weights``
        (:func:`weight_features`); ``loop_gain_at_peak`` (:math:`\bar\sigma` of the
        unweighted transfer at :math:`f^*`); ``plant_modes`` and ``plant_critical_hz``;
        ``modal_error`` (relative error of the modal reconstruction of :math:`N_{11}` at the
        peak) and ``eigvec_cond``; ``sensor_zeros`` and ``sensor_dc_gain`` (with
        ``selfsensing``); ``cause`` and ``sentence``; when the peak is at a grid end,
        ``interior`` holds the same attribution for the largest interior local maximum.
    """
    from .generalized_plant import n11_channels, n11_function

    ri, ci, wrow = n11_channels(loop, case)
    dt, f_pk, grid = float(loop.dt), float(sweep.peak_hz), np.asarray(sweep.freqs_hz)
    wfun = lambda hz: np.array([complex(np.squeeze(weights[k](2j * np.pi * hz))) for k in wrow])  # noqa: E731
    lam, res, D, cond = modal_terms(loop, ri, ci)
    modal = (lam, res, D, dt, wfun)
    exact = n11_function(loop, weights, case)(f_pk)
    modal_err = _sigma(_n11_modal(lam, res, D, dt, wfun)(f_pk) - exact) / max(_sigma(exact), 1e-300)
    pm = discrete_modes(plant.poles, dt) if plant is not None else []
    crit = max((m["f_hz"] for m in pm if m["abs_z"] >= 1.0), default=None)
    edge = "low" if f_pk <= grid.min() else "high" if f_pk >= grid.max() else None
    zeros, dc = sensor_zeros(selfsensing, dt) if selfsensing is not None else ([], None)
    a = _attribute(loop, weights, case, f_pk, sweep.peak, grid, modal)
    a["sensor_zeros"], a["sensor_dc_gain"] = zeros, dc
    a["cause"], a["sentence"] = _verdict(a, edge, crit)
    inner = _interior_max(sweep) if edge else None
    if inner is not None:
        b = _attribute(loop, weights, case, inner[0], inner[1], grid, modal)
        b["sensor_zeros"], b["sensor_dc_gain"] = zeros, dc
        b["cause"], b["sentence"] = _verdict(b, None, crit)
        b.pop("modes")
        a["sentence"] += f". Largest interior maximum: {b['sentence']}"
    modes = a.pop("modes")
    strip = lambda m: {k: v for k, v in m.items() if k != "index"}  # noqa: E731
    return {"case": case, **a, "at_grid_edge": edge, "interior": None if inner is None else b,
            "least_damped": [strip(m) for m in modes if grid[0] <= m["f_hz"] <= grid[-1]][:n_modes],
            "dzeta": DZETA, "weights": {k: weight_features(weights[k], f_pk, grid) for k in dict.fromkeys(wrow)},
            "plant_modes": pm[:n_modes], "plant_critical_hz": crit, "modal_error": float(modal_err),
            "eigvec_cond": cond}
