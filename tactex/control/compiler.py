"""The controllers' kernel compiler: numba's njit with the settings every compiled controller kernel shares.

It lives apart from the kernels it compiles (:mod:`tactex.control.joint_kernels`,
:mod:`tactex.control.va_ufic_tick`), so that they import it and the registry of compiled kernels
imports them, without an import cycle. numba is imported on the first call, not with this module.
"""

from __future__ import annotations

__all__ = ["compile_kernel"]


def compile_kernel(func, signature: str | None = None):
    """``func`` compiled by numba (for ``signature`` now, else at its first call), its machine code
    cached beside its module when that folder (or numba's per-user one) is writable."""
    from numba import njit

    args = (signature,) if signature else ()
    func = getattr(func, "py_func", func)  # a helper compiled by an earlier build
    # error_model="numpy": a division by zero gives inf/NaN as in the Python reference (the safety
    # layer then holds) instead of raising ZeroDivisionError out of the control loop
    try:
        return njit(*args, cache=True, nogil=True, error_model="numpy")(func)
    except RuntimeError:  # no writable cache location anywhere: compile in every process
        return njit(*args, nogil=True, error_model="numpy")(func)
