r"""The closed loop of the identified subsystems (paper Fig. 3), its simulation and d2c.

:func:`fig3_loop` is the one builder of the Fig. 3 loop (signal names and flow in
:mod:`ssamb.channels`); the nominal closed loop (:func:`assemble_closed_loop`), the loop
transfer of one axis (:func:`loop_transfer`, for margins and the ISO 14839-3 sensitivity) and
the generalized plant with disturbance channels (:mod:`ssamb.generalized_plant`) are views of
it. All discrete, dt = 1/fs.

The identified models are affine (input ``one``, see :mod:`ssamb.identification`); the closed loop
then has the inputs ``r_x, r_y, inj_x, inj_y, one`` and the caller sets ``one = 1``. Its
operating point is the equilibrium :math:`x_{eq} = (I - A_{cl})^{-1} B_{cl} w_0`; the PID
integrators settle where ``x_meas = r_x`` and ``y_ss = r_y``.

Continuous-time equivalent (for μ)
----------------------------------
:func:`to_continuous` inverts either the bilinear (Tustin) map or the zero-order hold:

* ``'tustin'`` (default): :math:`A_c = \tfrac{2}{T}(A + I)^{-1}(A - I)`. The unit circle maps
  onto the imaginary axis, :math:`G_c(j\omega_c) = G_d(e^{j\omega T})` with
  :math:`\omega_c = \tfrac{2}{T}\tan(\omega T/2)`: every peak of the frequency response (hence
  μ and the H∞ norm) is preserved exactly, only the frequency axis is warped; stability is
  preserved exactly; defined unless A has an eigenvalue at -1. It also recovers the
  continuous PID exactly (the controller was discretised with Tustin).
* ``'zoh'``: :math:`[A_c\ B_c] = \tfrac{1}{T}\log\begin{bmatrix}A & B\\0 & I\end{bmatrix}`
  (matrix logarithm, MATLAB ``d2c`` default): poles map as :math:`s = \ln z / T`, the
  response matches at low frequency but not near Nyquist; undefined for eigenvalues on the
  negative real axis (e.g. a model of an oscillation at Nyquist).

Either way a discrete pole error :math:`\delta z` becomes :math:`\delta s \approx \delta z / T`
(:func:`d2c_pole_sensitivity`): the conversion amplifies estimation errors by about
:math:`f_s` = 83 300, as the paper warns.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Mapping, Sequence

import control
import numpy as np
import scipy.linalg

from .channels import CL_INPUTS, CL_OUTPUTS, CURRENTS, FEEDBACK, ONE, POSITIONS
from .identification import IdentifiedModel, nrmse_fit

__all__ = [
    "StabilityReport",
    "as_statespace",
    "fig3_loop",
    "interconnect_linear",
    "assemble_closed_loop",
    "loop_transfer",
    "stability",
    "equilibrium",
    "lti_initial_state",
    "simulate_closed_loop",
    "replay",
    "replay_from_operating_point",
    "replay_fits",
    "to_continuous",
    "d2c_error",
    "d2c_pole_sensitivity",
]


def as_statespace(sys, inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None,
                  name: str | None = None) -> control.StateSpace:
    """A named ``control.StateSpace`` from an :class:`~ssamb.identification.IdentifiedModel` or a
    StateSpace (renamed if ``inputs``/``outputs`` are given)."""
    if isinstance(sys, IdentifiedModel):
        sys = sys.to_statespace()
    if not isinstance(sys, control.StateSpace):
        sys = control.ss(sys)
    ins = list(inputs) if inputs is not None else list(sys.input_labels)
    outs = list(outputs) if outputs is not None else list(sys.output_labels)
    if len(ins) != sys.ninputs or len(outs) != sys.noutputs:
        raise ValueError(f"{name}: {sys.ninputs} inputs/{sys.noutputs} outputs, names {ins}/{outs}")
    return control.ss(sys.A, sys.B, sys.C, sys.D, sys.dt, inputs=ins, outputs=outs, name=name)


def _check_names(sys: control.StateSpace, name: str, inputs: Sequence[str], outputs: Sequence[str],
                 optional_inputs: Sequence[str] = ()):
    missing_in = [s for s in inputs if s not in sys.input_labels]
    missing_out = [s for s in outputs if s not in sys.output_labels]
    extra_in = [s for s in sys.input_labels if s not in inputs and s not in optional_inputs and s != ONE]
    if missing_in or missing_out or extra_in:
        raise ValueError(
            f"{name}: inputs {sys.input_labels} / outputs {sys.output_labels} do not match the "
            f"expected inputs {list(inputs)} (+ optional {list(optional_inputs) + [ONE]}) / outputs {list(outputs)}")


@dataclass(frozen=True)
class StabilityReport:
    """Spectral radius and unstable poles of a discrete-time system."""

    spectral_radius: float
    stable: bool
    unstable_poles: np.ndarray
    dt: float

    def __str__(self) -> str:
        s = "stable" if self.stable else f"UNSTABLE ({len(self.unstable_poles)} pole(s) |z| >= 1)"
        return f"max|eig| = {self.spectral_radius:.6f}: {s}"


def stability(sys: control.StateSpace) -> StabilityReport:
    r"""Stability of a discrete system: :math:`\rho(A) = \max_i |\lambda_i(A)| < 1`."""
    ev = np.linalg.eigvals(np.asarray(sys.A, float)) if sys.nstates else np.zeros(0)
    rho = float(np.max(np.abs(ev))) if ev.size else 0.0
    return StabilityReport(rho, rho < 1.0, ev[np.abs(ev) >= 1.0], float(sys.dt))


def _subsystems(plant, amplifier, selfsensing, pid_x, pid_y) -> list[control.StateSpace]:
    """The five blocks of Fig. 3, named, checked and on one numeric dt."""
    P = as_statespace(plant, name="plant")
    G = as_statespace(amplifier, name="amplifier")
    S = as_statespace(selfsensing, name="selfsensing")
    Cx = as_statespace(pid_x, inputs=["e_x"], outputs=["u_x"], name="pid_x")
    Cy = as_statespace(pid_y, inputs=["e_y"], outputs=["u_y"], name="pid_y")
    _check_names(P, "plant", CURRENTS, POSITIONS)
    _check_names(G, "amplifier", ("u_x_cmd", "u_y_cmd"), CURRENTS, optional_inputs=POSITIONS)
    if len([c for c in S.input_labels if c != ONE]) != 1:
        raise ValueError(f"selfsensing: must be SISO (one input besides '{ONE}'), got {S.input_labels}")
    _check_names(S, "selfsensing", (), ("y_ss",), optional_inputs=("i_ypos", "y_meas"))
    for sysname, s in (("pid_x", Cx), ("pid_y", Cy)):
        if s.ninputs != 1 or s.noutputs != 1:
            raise ValueError(f"{sysname} must be SISO")
    blocks = (P, G, S, Cx, Cy)
    dts = {s.name: s.dt for s in blocks}
    if any(dt in (None, 0, True) for dt in dts.values()):
        raise ValueError(f"all subsystems must be discrete with a numeric dt; got {dts}")
    dt0 = float(P.dt)
    if any(abs(float(dt) - dt0) > 1e-9 * dt0 for dt in dts.values()):
        raise ValueError(f"subsystems have different sampling times: {dts}")
    return [control.ss(s.A, s.B, s.C, s.D, dt0, inputs=s.input_labels, outputs=s.output_labels, name=s.name)
            for s in blocks]


def _junctions(dt: float, open_at: str | None) -> list:
    """Summing junctions of Fig. 3: errors (or the loop break) and commands."""
    sums = []
    for axis in ("x", "y"):
        if axis == open_at:
            sums.append(control.summing_junction(inputs=[f"e_{axis}_in"], output=f"e_{axis}", dt=dt,
                                                 name=f"sum_e{axis}"))
        else:
            sums.append(control.summing_junction(inputs=[f"r_{axis}", "-" + FEEDBACK[axis]], output=f"e_{axis}",
                                                 dt=dt, name=f"sum_e{axis}"))
        sums.append(control.summing_junction(inputs=[f"u_{axis}", f"inj_{axis}"], output=f"u_{axis}_cmd", dt=dt,
                                             name=f"sum_u{axis}"))
    return sums


def interconnect_linear(blocks: Sequence[control.StateSpace], inputs: Sequence[str], outputs: Sequence[str]
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    r"""Closed-loop matrices of named discrete state-space blocks connected by signal name.

    Every block output is a signal; a block input takes the signal of its name, else the
    external input of that name (``inputs``), else zero. With the blocks stacked
    (:math:`x^+ = A x + B u`, :math:`y = C x + D u`, block-diagonal) and the connections
    :math:`u = M y + N w`:

    .. math::

        y = L (C x + D N w), \quad L = (I - D M)^{-1}, \qquad
        A_{cl} = A + B M L C, \quad B_{cl} = B (M L D N + N), \quad
        C_{cl} = S L C, \quad D_{cl} = S L D N,

    with :math:`S` selecting ``outputs`` from :math:`y`. The states are the blocks' in block
    order, as :func:`control.interconnect` orders them; the matrices agree with it to
    round-off (it evaluates the same static map signal by signal, in Python: 25 ms a loop).

    Raises
    ------
    ValueError
        A signal named by two blocks or an unknown output.
    RuntimeError
        An algebraic loop: a cycle of feedthrough links (:math:`D M` not nilpotent), which
        :func:`control.interconnect` refuses as well.
    """
    index, ny = {}, 0
    for b in blocks:
        for k, lab in enumerate(b.output_labels):
            if lab in index:
                raise ValueError(f"signal '{lab}' is the output of two blocks")
            index[lab] = ny + k
        ny += b.noutputs
    unknown = [o for o in outputs if o not in index]
    if unknown:
        raise ValueError(f"outputs {unknown} are no block's output")
    ns, ms, ps = ([b.nstates for b in blocks], [b.ninputs for b in blocks], [b.noutputs for b in blocks])
    # scipy's block_diag keeps a block with no states as (0, 0), (0, m) and (p, 0)
    A, B, C, D = (scipy.linalg.block_diag(*[np.reshape(getattr(b, k), (r, c)) for b, r, c in zip(blocks, rows, cols)])
                  for k, rows, cols in (("A", ns, ns), ("B", ns, ms), ("C", ps, ns), ("D", ps, ms)))
    labels = [lab for b in blocks for lab in b.input_labels]
    M, N = np.zeros((len(labels), ny)), np.zeros((len(labels), len(inputs)))
    where = {w: j for j, w in enumerate(inputs)}
    for k, lab in enumerate(labels):
        if lab in index:
            M[k, index[lab]] = 1.0
        elif lab in where:
            N[k, where[lab]] = 1.0
    DM = D @ M
    # entry (i, j) of the ny-th power of the link graph counts the paths of ny direct links from
    # signal j to signal i: one exists only through a cycle
    if ny and np.linalg.matrix_power((DM != 0).astype(float), ny).any():
        raise RuntimeError("algebraic loop: the blocks' feedthrough (D) closes a loop")
    L = np.linalg.inv(np.eye(ny) - DM)
    S = np.zeros((len(outputs), ny))
    S[np.arange(len(outputs)), [index[o] for o in outputs]] = 1.0
    LC, LDN = L @ C, L @ D @ N
    return A + B @ M @ LC, B @ (M @ LDN + N), S @ LC, S @ LDN


def fig3_loop(plant, amplifier, selfsensing, pid_x, pid_y, *, inputs: Sequence[str] | None = None,
              outputs: Sequence[str] = CL_OUTPUTS, disturbed: Sequence[str] = (), open_at: str | None = None,
              name: str = "amb_lti") -> control.StateSpace:
    r"""The closed loop of Fig. 3 -- the one builder every stage uses.

    Parameters
    ----------
    plant, amplifier, selfsensing : IdentifiedModel or StateSpace
        Subsystem models named as in :mod:`ssamb.channels` (plant: currents -> ``x_meas,
        y_meas``; amplifier: ``u_x_cmd, u_y_cmd`` [+ ``x_meas, y_meas``] -> currents;
        self-sensing: ``y_meas`` or ``i_ypos`` -> ``y_ss``; each may be affine with ``one``).
    pid_x, pid_y : StateSpace
        SISO discrete controllers (error in, current out).
    inputs : sequence of str, optional
        External inputs, from ``r_x, r_y, inj_x, inj_y, one``, ``d_<signal>`` of every disturbed
        signal and ``e_<axis>_in`` of an open loop. Default: every one of them that exists.
        The others stay deliberately open (zero) and are exempt from python-control's
        unused-signal check; every other unconnected signal still raises its warning.
    outputs : sequence of str
        Any subsystem signal (default :data:`~ssamb.channels.CL_OUTPUTS`).
    disturbed : sequence of str
        Subsystem outputs :math:`s` that get an additive input, :math:`s = \bar s + d_s` (the
        disturbance channels of the generalized plant, Figs. 5-6).
    open_at : {None, 'x', 'y'}
        Break the loop at that axis' controller input: the error is the external input
        ``e_<axis>_in`` and the feedback signal :math:`y` (:data:`~ssamb.channels.FEEDBACK`) an
        output, so the loop transfer is :math:`L = y/e_{in}` and, closed by :math:`e = r - y`,
        :math:`S = 1/(1 + L)`.

    Raises
    ------
    ValueError
        Mixed sampling times, wrong signal names, or an algebraic loop (D-matrices closing a
        loop: identify the amplifier or self-sensing strictly proper, ``D_required=False``).
    """
    blocks = _subsystems(plant, amplifier, selfsensing, pid_x, pid_y)
    dt = float(blocks[0].dt)
    for i, b in enumerate(blocks[:3]):
        outs = [o + "_nom" if o in disturbed else o for o in b.output_labels]
        blocks[i] = control.ss(b.A, b.B, b.C, b.D, dt, inputs=b.input_labels, outputs=outs, name=b.name)
    own = {o for b in blocks[:3] for o in b.output_labels}
    unknown = [d for d in disturbed if d + "_nom" not in own]
    if unknown:
        raise ValueError(f"disturbed signals {unknown} are not subsystem outputs")
    blocks += [control.summing_junction(inputs=[d + "_nom", "d_" + d], output=d, dt=dt, name="add_" + d)
               for d in disturbed]
    blocks += _junctions(dt, open_at)
    has_one = any(ONE in b.input_labels for b in blocks[:3])
    available = [c for c in CL_INPUTS if (c != ONE or has_one) and c != f"r_{open_at}"]
    available += ["d_" + d for d in disturbed] + ([f"e_{open_at}_in"] if open_at else [])
    inputs = available if inputs is None else list(inputs)
    bad = [c for c in inputs if c not in available]
    if bad:
        raise ValueError(f"inputs {bad} not available (available: {available})")
    try:
        A, B, C, D = interconnect_linear(blocks, inputs, list(outputs))
    except RuntimeError as exc:
        raise ValueError(
            "algebraic loop in the closed-loop assembly: the feedthrough (D) matrices of the "
            "PID, amplifier and self-sensing models close a loop without delay; identify the "
            "amplifier or the self-sensing model strictly proper (D_required=False)") from exc
    return control.ss(A, B, C, D, dt, inputs=inputs, outputs=list(outputs), name=name)


def assemble_closed_loop(plant, amplifier, selfsensing, pid_x, pid_y, *, require_stable: bool = False,
                         name: str = "amb_lti") -> control.StateSpace:
    """The nominal closed loop of Fig. 3 (:func:`fig3_loop` with the reference and injection
    inputs, outputs :data:`~ssamb.channels.CL_OUTPUTS`); warns, or with ``require_stable``
    raises ``ValueError``, when it is unstable (:func:`stability`)."""
    cl = fig3_loop(plant, amplifier, selfsensing, pid_x, pid_y, name=name)
    rep = stability(cl)
    if not rep.stable:
        msg = f"closed-loop LTI model is unstable: {rep}"
        if require_stable:
            raise ValueError(msg)
        warnings.warn(msg, stacklevel=2)
    return cl


def loop_transfer(plant, amplifier, selfsensing, pid_x, pid_y, axis: str) -> control.StateSpace:
    r"""Loop transfer :math:`L` of one axis broken at its controller input, the other axis
    closed: :math:`L = y_{fb}/e_{in}`, so that :math:`S = 1/(1 + L)` (ISO 14839-3)."""
    if axis not in FEEDBACK:
        raise ValueError(f"axis '{axis}': must be x or y")
    sys = fig3_loop(plant, amplifier, selfsensing, pid_x, pid_y, inputs=[f"e_{axis}_in"],
                    outputs=[FEEDBACK[axis]], open_at=axis, name=f"loop_{axis}")
    return control.ss(sys.A, sys.B, sys.C, sys.D, sys.dt)


def _input_matrix(sys: control.StateSpace, n: int, signals: Mapping[str, np.ndarray | float]) -> np.ndarray:
    U = np.zeros((sys.ninputs, n))
    for i, name in enumerate(sys.input_labels):
        if name == ONE:
            U[i] = 1.0
        elif signals.get(name) is not None:
            U[i] = np.broadcast_to(np.asarray(signals[name], float), (n,))
    return U


def equilibrium(sys: control.StateSpace, w0: np.ndarray) -> np.ndarray:
    r"""Equilibrium state for the constant input :math:`w_0`: :math:`(I - A)x = B w_0`."""
    A = np.asarray(sys.A, float)
    try:
        return np.linalg.solve(np.eye(A.shape[0]) - A, np.asarray(sys.B, float) @ w0)
    except np.linalg.LinAlgError:
        raise ValueError("the system has a pole at z = 1: no unique equilibrium") from None


def lti_initial_state(cl: control.StateSpace, r_x0: float = 0.0, r_y0: float = 0.0) -> np.ndarray:
    """Equilibrium of the closed loop for constant references and no injection (the state a
    nonlinear run settled at its operating point corresponds to)."""
    w0 = np.array([{"r_x": r_x0, "r_y": r_y0, ONE: 1.0}.get(n, 0.0) for n in cl.input_labels])
    return equilibrium(cl, w0)


def simulate_closed_loop(sys: control.StateSpace, t, r_x, r_y, inj_x=None, inj_y=None,
                         x0=None) -> dict:
    """Simulate the closed loop; return a dict with the column names of the nonlinear data.

    Parameters
    ----------
    sys : control.StateSpace
        From :func:`assemble_closed_loop` (``one`` is set to 1 here).
    t : array_like (N,)
        Time, s, uniformly spaced at ``sys.dt``.
    r_x, r_y, inj_x, inj_y : array_like (N,) or float
        References (m) and current injections (A); the injections default to 0.
    x0 : None or array
        Initial state; ``None`` is the equilibrium for the inputs at ``t[0]`` held constant,
        so that data starting at the operating point show no start-up transient.

    Returns
    -------
    dict
        ``t, r_x, r_y, inj_x, inj_y`` and every output (``x_meas, y_meas, y_ss, i_ypos, i_yneg,
        i_xpos, i_xneg, u_x, u_y``), plus ``states`` (N, n).
    """
    t = np.asarray(t, float).ravel()
    n = len(t)
    if n < 1:
        raise ValueError("t is empty")
    if n > 1:
        dt = np.diff(t)
        if not np.allclose(dt, sys.dt, rtol=1e-6, atol=0):
            raise ValueError(f"t must be uniformly spaced at dt = {sys.dt} s (median step {np.median(dt)} s)")
    sig = {"r_x": r_x, "r_y": r_y, "inj_x": 0.0 if inj_x is None else inj_x,
           "inj_y": 0.0 if inj_y is None else inj_y}
    for k, v in sig.items():
        a = np.asarray(v, float)
        if a.ndim and a.shape != (n,):
            raise ValueError(f"{k} has shape {a.shape}, t has {n} samples")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{k} has non-finite values")
    U = _input_matrix(sys, n, sig)
    if x0 is None:
        x0 = equilibrium(sys, U[:, 0])
    A, B, C, D = (np.asarray(M, float) for M in (sys.A, sys.B, sys.C, sys.D))
    from .lsim import dlsim

    x, y = dlsim(A, B, C, D, U.T, np.asarray(x0, float).ravel())
    out = {"t": t}
    out.update({k: np.broadcast_to(np.asarray(v, float), (n,)).copy() for k, v in sig.items()})
    out.update({name: y[:, i] for i, name in enumerate(sys.output_labels)})
    out["states"] = np.asarray(x).reshape(n, -1)
    return out


def replay(sys: control.StateSpace, arrays: Mapping[str, np.ndarray], x0=None) -> dict:
    """:func:`simulate_closed_loop` driven by the references and injections of a data dict.

    ``arrays`` holds the measured-data columns (``t``, ``r_x``, ``r_y`` and, if present,
    ``inj_x``, ``inj_y``); the result has the same column names, so that a comparison is one
    line, e.g. ``nrmse_fit(arrays["x_meas"], replay(cl, arrays)["x_meas"])``.
    """
    missing = [c for c in ("t", "r_x", "r_y") if c not in arrays]
    if missing:
        raise ValueError(f"replay: missing column(s) {', '.join(missing)}")
    return simulate_closed_loop(sys, arrays["t"], arrays["r_x"], arrays["r_y"], arrays.get("inj_x"),
                                arrays.get("inj_y"), x0=x0)


def replay_from_operating_point(sys: control.StateSpace, arrays: Mapping[str, np.ndarray]) -> dict:
    """:func:`replay` of a record that starts at its settled operating point.

    The nonlinear runs start from the operating point with no injection (the pre-roll), so the
    loop starts at its equilibrium for the references at t = 0 and zero injection
    (:func:`lti_initial_state`), not for the first input sample (which would put a pulse's DC
    response into the initial state).
    """
    x0 = lti_initial_state(sys, float(np.ravel(arrays["r_x"])[0]), float(np.ravel(arrays["r_y"])[0]))
    return replay(sys, arrays, x0=x0)


def replay_fits(sys: control.StateSpace, arrays: Mapping[str, np.ndarray],
                channels: Sequence[str] = ("x_meas", "y_meas")) -> dict:
    """Fit (:func:`~ssamb.identification.nrmse_fit`, %) per channel of
    :func:`replay_from_operating_point` against the record: channel -> fit."""
    out = replay_from_operating_point(sys, arrays)
    return {c: float(nrmse_fit(np.asarray(arrays[c], float), out[c])) for c in channels}


# ----------------------------------------------------------------------------------------
# discrete -> continuous
# ----------------------------------------------------------------------------------------
def to_continuous(sys: control.StateSpace, method: str = "tustin") -> control.StateSpace:
    r"""Continuous-time equivalent of a discrete state-space system (names kept).

    ``method='tustin'``: the inverse of scipy's bilinear ``cont2discrete`` (generalised
    bilinear, α = 1/2), with :math:`M = I - \tfrac{T}{2} A_c`:

    .. math::

        A_c = \tfrac{2}{T}(A + I)^{-1}(A - I),\quad B_c = M B / T,\quad
        C_c = C M,\quad D_c = D - \tfrac12 C_c B.

    ``method='zoh'``: :math:`\begin{bmatrix}A_c & B_c\\ 0 & 0\end{bmatrix} = \tfrac1T
    \log\begin{bmatrix}A & B\\ 0 & I\end{bmatrix}`, :math:`C_c = C`, :math:`D_c = D`
    (``scipy.linalg.logm``; python-control has no d2c).

    Raises
    ------
    ValueError
        Continuous or unknown-dt input; 'tustin' with an eigenvalue at -1; 'zoh' with an
        eigenvalue on the closed negative real axis (no real logarithm).
    """
    if not control.isdtime(sys, strict=True) or sys.dt in (None, True):
        raise ValueError("to_continuous needs a discrete system with a numeric dt")
    T = float(sys.dt)
    A, B, C, D = (np.asarray(M, float) for M in (sys.A, sys.B, sys.C, sys.D))
    n, m = B.shape
    ev = np.linalg.eigvals(A) if n else np.zeros(0)
    if method == "tustin":
        if n and np.min(np.abs(ev + 1.0)) < 1e-10:
            raise ValueError("Tustin inverse undefined: A has an eigenvalue at z = -1")
        I = np.eye(n)
        Ac = (2.0 / T) * np.linalg.solve(A + I, A - I)
        M = I - 0.5 * T * Ac
        Bc = M @ B / T
        Cc = C @ M
        Dc = D - 0.5 * Cc @ B
    elif method == "zoh":
        bad = ev[(np.abs(ev.imag) < 1e-12) & (ev.real <= 0)]
        if bad.size:
            raise ValueError(
                f"ZOH inverse undefined: A has eigenvalue(s) {bad} on the closed negative real axis "
                "(no real matrix logarithm); use method='tustin'")
        Maug = np.zeros((n + m, n + m))
        Maug[:n, :n] = A
        Maug[:n, n:] = B
        Maug[n:, n:] = np.eye(m)
        L = scipy.linalg.logm(Maug) / T
        if np.max(np.abs(L.imag)) > 1e-8 * max(1.0, np.max(np.abs(L.real))):
            raise ValueError("ZOH inverse: the matrix logarithm is not real; use method='tustin'")
        L = L.real
        Ac, Bc, Cc, Dc = L[:n, :n], L[:n, n:], C, D
    else:
        raise ValueError(f"method must be 'tustin' or 'zoh' (got {method!r})")
    return control.ss(Ac, Bc, Cc, Dc, inputs=list(sys.input_labels), outputs=list(sys.output_labels),
                      name=f"{sys.name}_c" if sys.name else None)


def _freqresp(sys, w_rad_s, discrete: bool):
    """Complex response array (n_freq, l, m) of a StateSpace at the angular frequencies."""
    if discrete:
        pts = np.exp(1j * w_rad_s * sys.dt)
    else:
        pts = 1j * w_rad_s
    A, B, C, D = (np.asarray(M, float) for M in (sys.A, sys.B, sys.C, sys.D))
    n = A.shape[0]
    out = np.empty((len(pts), C.shape[0], B.shape[1]), complex)
    for k, z in enumerate(pts):
        out[k] = C @ np.linalg.solve(z * np.eye(n) - A, B) + D if n else D
    return out


def d2c_error(sysd: control.StateSpace, sysc: control.StateSpace, freqs_hz=None, warp: bool = False) -> dict:
    r"""Difference between the discrete and continuous frequency responses up to Nyquist.

    .. math::

        e_{dB}(f) = 20\log_{10}|G_c(j2\pi f')| - 20\log_{10}|G_d(e^{j2\pi f T})|,\quad
        e_{deg}(f) = \angle G_c(j2\pi f') - \angle G_d(e^{j 2\pi f T})

    per input/output pair, with :math:`f' = f` (same physical frequency, the default: what μ
    on the continuous model sees) or, with ``warp=True``, :math:`f' = \tan(\pi f T)/(\pi T)`
    (the Tustin-warped frequency, where a Tustin conversion is exact: a check of the
    numerics). Phase differences are wrapped to (-180, 180].

    Returns
    -------
    dict
        ``freqs_hz`` (n_f,), ``mag_db`` and ``phase_deg`` (n_f, l, m),
        ``max_abs_mag_db``, ``max_abs_phase_deg`` and the frequency where the magnitude error
        first exceeds 1 dB (``f_1db_hz``, None if never).
    """
    T = float(sysd.dt)
    fn = 0.5 / T
    if freqs_hz is None:
        freqs_hz = np.geomspace(1.0, 0.999 * fn, 400)
    f = np.asarray(freqs_hz, float)
    if np.any(f <= 0) or np.any(f >= fn):
        raise ValueError(f"frequencies must lie in (0, Nyquist = {fn} Hz)")
    w = 2 * np.pi * f
    Gd = _freqresp(sysd, w, True)
    wc = (2.0 / T) * np.tan(w * T / 2.0) if warp else w
    Gc = _freqresp(sysc, wc, False)
    with np.errstate(divide="ignore", invalid="ignore"):
        mag = 20 * np.log10(np.abs(Gc)) - 20 * np.log10(np.abs(Gd))
        ph = np.angle(Gc / Gd, deg=True)
    mag = np.where(np.isfinite(mag), mag, np.nan)
    amax = np.nanmax(np.abs(mag), axis=(1, 2)) if mag.size else np.zeros(len(f))
    over = np.where(amax > 1.0)[0]
    return {
        "freqs_hz": f,
        "mag_db": mag,
        "phase_deg": ph,
        "max_abs_mag_db": float(np.nanmax(np.abs(mag))),
        "max_abs_phase_deg": float(np.nanmax(np.abs(ph))),
        "f_1db_hz": float(f[over[0]]) if over.size else None,
    }


def d2c_pole_sensitivity(sysd: control.StateSpace, method: str = "tustin") -> dict:
    r"""How much d2c amplifies a pole error: :math:`|ds/dz|` per discrete pole.

    ZOH: :math:`s = \ln z/T \Rightarrow |ds/dz| = 1/(T|z|)`; Tustin:
    :math:`s = \tfrac2T\tfrac{z-1}{z+1} \Rightarrow |ds/dz| = \tfrac{4}{T|z+1|^2}`. Both are
    :math:`\approx f_s` for poles near :math:`z = 1` (the slow poles of a model sampled at
    83.3 kHz): an error of :math:`10^{-5}` in a discrete pole moves the continuous pole by
    about 0.8 rad/s.

    Returns
    -------
    dict
        ``poles_z``, ``poles_s``, ``gain`` (:math:`|ds/dz|` per pole, 1/s), ``fs_hz``,
        ``gain_over_fs`` (gain / fs).
    """
    T = float(sysd.dt)
    z = np.linalg.eigvals(np.asarray(sysd.A, float))
    if method == "zoh":
        g = 1.0 / (T * np.abs(z))
        s = np.log(z.astype(complex)) / T
    elif method == "tustin":
        g = 4.0 / (T * np.abs(z + 1.0) ** 2)
        s = (2.0 / T) * (z - 1.0) / (z + 1.0)
    else:
        raise ValueError(f"method must be 'tustin' or 'zoh' (got {method!r})")
    return {"poles_z": z, "poles_s": s, "gain": g, "fs_hz": 1.0 / T, "gain_over_fs": g * T}


def d2c_summary(sysd: control.StateSpace, method: str = "tustin", f_max_hz: float = 1e3) -> dict:
    """How faithful the continuous equivalent is (:func:`d2c_error` on 300 log-spaced
    frequencies up to 0.45 fs, same physical frequency) and how much it amplifies pole errors
    (:func:`d2c_pole_sensitivity`): the largest errors below ``f_max_hz`` and overall."""
    sysc = to_continuous(sysd, method)
    freqs = np.logspace(-1, np.log10(0.45 / float(sysd.dt)), 300)
    err = d2c_error(sysd, sysc, freqs, warp=False)
    sens = d2c_pole_sensitivity(sysd, method)
    low = err["freqs_hz"] <= f_max_hz
    return {"max_mag_error_db_below_1khz": float(np.nanmax(np.abs(err["mag_db"][low]))),
            "max_phase_error_deg_below_1khz": float(np.nanmax(np.abs(err["phase_deg"][low]))),
            "max_mag_error_db": err["max_abs_mag_db"], "max_phase_error_deg": err["max_abs_phase_deg"],
            "f_1db_hz": err["f_1db_hz"], "pole_error_gain_max": float(np.max(np.abs(sens["gain"]))),
            "pole_error_gain_over_fs_max": float(np.max(np.abs(sens["gain_over_fs"])))}
