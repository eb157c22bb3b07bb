"""The joint-space end of the task-space controllers, compiled with numba (the optional ``fast`` extra).

Two pieces of every contact tick are small dense algebra on the 7 × 7 mass matrix and the 6 × 7
Jacobian: UFIC's latency-shaped τ = M (M + h·Jₜᵀ(D + h·K)Jₜ)⁻¹ Jᵀf
(:meth:`tactex.control.ufic.UficController.joint_torque`) and the null-space posture torque
(:class:`tactex.control.nullspace.NullspacePosture`). As numpy they are a dozen small calls each,
and the calls' dispatch, not their arithmetic, is their cost, paid between a robot state and its
command (docs/real_robot.md). Here each is one
compiled call doing the same operations in the same order. The numpy forms stay the reference:
the tests check that both give the same torque to round-off.

numba is imported on the first :func:`kernels` call, not with this module, and the machine code is
made then for the one set of argument types the controllers use (once per machine: numba caches
it beside this file, or in a per-user folder). A :class:`~tactex.tasks.runner.ControlLoop` asks for
the kernels when it is made, so that controllers built later, between moves while a real robot's
torque control runs, find them ready. Without numba (or after :func:`disable`) the controllers use
numpy.
"""

from __future__ import annotations

import importlib.util
import logging
import math
import warnings
from typing import NamedTuple

import numpy as np

from tactex.control.compiler import compile_kernel

_log = logging.getLogger(__name__)

__all__ = ["JointKernels", "available", "compile_kernel", "disable", "kernels", "latency_shaped_task_torque",
           "limit_torque", "posture_torque", "run", "state_finite"]


def _cholesky_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a·x = b for a symmetric positive definite (n, n) ``a`` (overwritten by its Cholesky
    factor) and (n,) ``b``. Written out rather than LAPACK: for n ≤ 7 the call, the copies into
    Fortran order and the pivoting cost more than the arithmetic. A matrix that is not positive
    definite or not finite gives NaN (the safety layer then holds the last command)."""
    n = b.shape[0]
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= a[j, k] * a[j, k]
        if not s > 0.0:
            return np.full(n, np.nan)
        ljj = np.sqrt(s)
        a[j, j] = ljj
        for i in range(j + 1, n):
            s = a[i, j]
            for k in range(j):
                s -= a[i, k] * a[j, k]
            a[i, j] = s / ljj
    x = b.copy()
    for i in range(n):  # L y = b
        s = x[i]
        for k in range(i):
            s -= a[i, k] * x[k]
        x[i] = s / a[i, i]
    for i in range(n - 1, -1, -1):  # Lᵀ x = y
        s = x[i]
        for k in range(i + 1, n):
            s -= a[k, i] * x[k]
        x[i] = s / a[i, i]
    return x


def _matvec(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """a·x for a small (m, n) matrix, written out (see :func:`_cholesky_solve`)."""
    out = np.zeros(a.shape[0])
    for i in range(a.shape[0]):
        s = 0.0
        for j in range(a.shape[1]):
            s += a[i, j] * x[j]
        out[i] = s
    return out


def latency_shaped_task_torque(jac: np.ndarray, rot: np.ndarray, mass: np.ndarray, f_world: np.ndarray,
                               d_tool: np.ndarray, k_tool: np.ndarray, horizon_s: float) -> np.ndarray:
    """M (M + h·Jₜᵀ diag(D + h·K) Jₜ)⁻¹ Jᵀ f [N·m], Jₜ = [RᵀJ_v; RᵀJ_ω] the Jacobian in the tool frame.

    Args:
        jac: (6, 7) TCP Jacobian, world frame. rot: (3, 3) world_R_tool. mass: (7, 7) [kg·m²].
        f_world: (6,) world wrench [N, N·m]. d_tool, k_tool: (6,) tool-frame damping [N·s/m, N·m·s/rad]
        and stiffness [N/m, N·m/rad]. horizon_s: h [s], > 0.
    """
    n = jac.shape[1]
    tau0 = np.zeros(n)
    for i in range(6):
        fi = f_world[i]
        for j in range(n):
            tau0[j] += fi * jac[i, j]
    jt = np.zeros((6, n))
    for a in range(3):
        for j in range(n):
            jt[a, j] = rot[0, a] * jac[0, j] + rot[1, a] * jac[1, j] + rot[2, a] * jac[2, j]
            jt[3 + a, j] = rot[0, a] * jac[3, j] + rot[1, a] * jac[4, j] + rot[2, a] * jac[5, j]
    a_mat = mass.copy()
    for i in range(6):
        g = horizon_s * (d_tool[i] + horizon_s * k_tool[i])
        for r in range(n):
            gr = g * jt[i, r]
            for c in range(n):
                a_mat[r, c] += gr * jt[i, c]
    return _matvec(mass, _cholesky_solve(a_mat, tau0))


def posture_torque(jac: np.ndarray, mass: np.ndarray, q_posture: np.ndarray, q: np.ndarray, dq: np.ndarray,
                   stiffness: float, damping: float, horizon_s: float, pinv_damping: float) -> np.ndarray:
    """The null-space posture torque [N·m]: N τ₀ with τ₀ = k (q_d − q) − d q̇ and
    N τ₀ = τ₀ − Jᵀ(J Jᵀ + δ²I)⁻¹ J τ₀, then M (M + (h·d + h²·k) I)⁻¹ (·) when h > 0.

    Args:
        jac: (6, 7) TCP Jacobian. mass: (7, 7) [kg·m²]. q_posture, q, dq: (7,) [rad, rad/s].
        stiffness [N·m/rad], damping [N·m·s/rad], horizon_s h [s] ≥ 0, pinv_damping δ [-].
    """
    n = q.shape[0]
    m = jac.shape[0]
    tau = stiffness * (q_posture - q) - damping * dq
    jjt = np.zeros((m, m))
    for i in range(m):
        for k in range(m):
            s = 0.0
            for j in range(n):
                s += jac[i, j] * jac[k, j]
            jjt[i, k] = s
        jjt[i, i] += pinv_damping * pinv_damping
    y = _cholesky_solve(jjt, _matvec(jac, tau))
    for j in range(n):  # τ − Jᵀ y
        s = 0.0
        for i in range(m):
            s += jac[i, j] * y[i]
        tau[j] -= s
    if horizon_s > 0.0:
        a_mat = mass.copy()
        extra = horizon_s * damping + horizon_s * horizon_s * stiffness
        for i in range(n):
            a_mat[i, i] += extra
        tau = _matvec(mass, _cholesky_solve(a_mat, tau))
    return tau


def state_finite(t: float, q: np.ndarray, dq: np.ndarray, tau: np.ndarray, pos: np.ndarray, rot: np.ndarray,
                 twist: np.ndarray, jac: np.ndarray, mass: np.ndarray, coriolis: np.ndarray, gravity: np.ndarray,
                 wrench: np.ndarray) -> bool:
    """Whether every number of a :class:`~tactex.control.state.RobotState` (its fields in order) is
    finite: the safety layer's first check, one call instead of a concatenation of twelve arrays."""
    if not math.isfinite(t):
        return False
    for a in (q, dq, tau, pos, twist, coriolis, gravity, wrench):
        for x in a:
            if not math.isfinite(x):
                return False
    for m in (rot, jac, mass):
        for i in range(m.shape[0]):
            for j in range(m.shape[1]):
                if not math.isfinite(m[i, j]):
                    return False
    return True


#: :func:`limit_torque`'s flags: the command was not finite (nothing changed), the torque limit,
#: the rate limit acted; bit ``LIMIT_NEAR_SHIFT + j``: joint j within the margin of a limit.
LIMIT_NOT_FINITE, LIMIT_TORQUE, LIMIT_RATE, LIMIT_NEAR_SHIFT = 1, 2, 4, 3
#: Depth into a joint's repulsion band over which the repulsion's damping fades in [rad]: switched on at the
#: band's edge, damping × speed would step the command there (2 N·m·s/rad at 0.7 rad/s: 1.4 N·m in one tick,
#: over the robot's torque-rate limit).
LIMIT_DAMPING_RAMP_RAD = 0.02


def limit_torque(tau: np.ndarray, prev: np.ndarray, tau_max: np.ndarray, q: np.ndarray, dq: np.ndarray,
                 lo_margin: np.ndarray, hi_margin: np.ndarray, stiffness: float, damping: float,
                 rate_step: float) -> int:
    """The safety layer's last step (:meth:`tactex.control.safety.SafetyLayer._finish`) on the
    controller's command ``tau`` [N·m]: the joint-limit repulsion (``stiffness`` [N·m/rad],
    ``damping`` [N·m·s/rad], faded in over :data:`LIMIT_DAMPING_RAMP_RAD`, beyond ``lo_margin``/``hi_margin``
    [rad]), then the torque (``tau_max``)
    and torque-rate (``rate_step`` [N·m] per tick from ``prev``) saturation. The result replaces
    ``prev`` in place. Returns the flags above; with a non-finite ``tau`` (or one whose sum
    overflows) nothing is changed."""
    n = tau.shape[0]
    total = 0.0  # finite iff its sum is, as the safety layer's Python check decides (an overflow holds too)
    for j in range(n):
        total += tau[j]
    if not math.isfinite(total):
        return LIMIT_NOT_FINITE
    flags = 0
    for j in range(n):
        x, p, m = tau[j], prev[j], tau_max[j]
        if q[j] < lo_margin[j] or q[j] > hi_margin[j]:
            flags |= 1 << (LIMIT_NEAR_SHIFT + j)
            if q[j] < lo_margin[j]:
                depth = lo_margin[j] - q[j]
                x += stiffness * depth - damping * min(depth / LIMIT_DAMPING_RAMP_RAD, 1.0) * dq[j]
            if q[j] > hi_margin[j]:
                depth = q[j] - hi_margin[j]
                x += -(stiffness * depth + damping * min(depth / LIMIT_DAMPING_RAMP_RAD, 1.0) * dq[j])
        if not math.isfinite(x):
            x = 0.0
        lo = p - rate_step
        hi = p + rate_step
        if lo < -m:
            lo = -m
        if hi > m:
            hi = m
        y = lo if x < lo else x
        y = hi if y > hi else y
        if y != x:
            if x > m or x < -m:
                flags |= LIMIT_TORQUE
                if y != (m if x > m else -m):
                    flags |= LIMIT_RATE
            else:
                flags |= LIMIT_RATE
        prev[j] = y
    return flags


class JointKernels(NamedTuple):
    """The compiled forms of :func:`latency_shaped_task_torque`, :func:`posture_torque`,
    :func:`tactex.control.va_ufic_tick.va_ufic_tick` (VA-UFIC's tick up to the world wrench),
    :func:`state_finite` and :func:`limit_torque`."""

    task_torque: object
    posture_torque: object
    va_ufic_tick: object = None
    state_finite: object = None
    limit_torque: object = None


_kernels: JointKernels | None = None
_failure: str | None = None


def available() -> bool:
    """Whether numba is installed (the ``fast`` extra); does not import it."""
    return importlib.util.find_spec("numba") is not None


def kernels() -> JointKernels | None:
    """The compiled kernels, built on the first call; None without numba, with ``NUMBA_DISABLE_JIT``
    set (it would run them as plain Python, slower than numpy), or after :func:`disable`."""
    global _kernels, _failure
    if _kernels is not None or _failure is not None:
        return _kernels
    if not available():
        _failure = "numba is not installed (the fast extra)"  # asked once: find_spec is not free
        return None
    _log.info("preparing the controllers' compiled kernels (numba compiles them once per machine)")
    try:
        from numba import config

        if config.DISABLE_JIT:
            return None
        f8v, f8m = "float64[::1]", "float64[:, ::1]"
        sig_task = f"{f8v}({f8m}, {f8m}, {f8m}, {f8v}, {f8v}, {f8v}, float64)"
        sig_posture = f"{f8v}({f8m}, {f8m}, {f8v}, {f8v}, {f8v}, float64, float64, float64, float64)"
        # the tick reads its inputs in any layout (a reference's rotation may be a transposed view)
        va, vm = "float64[:]", "float64[:, :]"
        sig_tick = (f"int64({f8v}, {f8v}, float64, {vm}, {va}, {va}, {va}, {va}, {vm}, {va}, {va}, float64, {va}, "
                    f"float64, {f8v})")
        global _cholesky_solve, _matvec
        # the kernels call these helpers by name: their compiled forms take the Python ones' place here
        _cholesky_solve, _matvec = compile_kernel(_cholesky_solve), compile_kernel(_matvec)
        task = compile_kernel(latency_shaped_task_torque, sig_task)
        posture = compile_kernel(posture_torque, sig_posture)
        from tactex.control.va_ufic_tick import va_ufic_tick

        tick = compile_kernel(va_ufic_tick, sig_tick)
        sig_finite = f"boolean(float64, {va}, {va}, {va}, {va}, {vm}, {va}, {vm}, {vm}, {va}, {va}, {va})"
        finite = compile_kernel(state_finite, sig_finite)
        sig_limit = f"int64({va}, {f8v}, {va}, {va}, {va}, {va}, {va}, float64, float64, float64)"
        limit = compile_kernel(limit_torque, sig_limit)
    except Exception as exc:  # numba's import, typing or compilation (e.g. a numba too old for numpy)
        reason = f"{type(exc).__name__}: {exc}"
        disable(reason)
        warnings.warn(f"the controllers' compiled kernels are unavailable, running numpy ({reason})",
                      RuntimeWarning, stacklevel=2)
        return None
    _kernels = JointKernels(task, posture, tick, finite, limit)
    return _kernels


def run(kernel, *args, then: str = "this controller runs numpy from now on"):
    """``kernel(*args)``'s result (a torque is NaN when an input is not finite, as with numpy: the
    safety layer then holds the last command); None, with a warning ending in ``then``, when the
    arrays are not the types the kernel was compiled for: the caller then uses its Python form from
    there on, since every failed dispatch costs about as much as that."""
    try:
        return kernel(*args)
    except TypeError as exc:
        types = ", ".join(f"{a.dtype}{'' if a.flags.c_contiguous else ' strided'}" if isinstance(a, np.ndarray)
                          else type(a).__name__ for a in args)
        warnings.warn(f"a compiled controller kernel cannot take ({types}): {exc}; {then}", RuntimeWarning,
                      stacklevel=3)
        return None


def disable(reason: str) -> None:
    """Stop offering the compiled kernels in this process (``reason``: why); controllers built
    afterwards use numpy."""
    global _kernels, _failure
    _kernels, _failure = None, reason
