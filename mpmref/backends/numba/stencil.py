r"""A particle's stencil along one axis as the Numba transfer kernels hold it: tuples, values a compiled loop keeps in
registers. The weights and slopes are the pointwise ones of :mod:`mpmref.backends.pointwise.stencil`, computed in
float64 (the position in cells is float64 in both dtypes) and cast to the run's type."""

import numpy as np
from numba import njit

from ..pointwise.stencil import kernel_axis


@njit(cache=True, inline="always")
def offsets(f, dx, S):
    """Node offsets :math:`(k - f)\\Delta x`, ``k = 0 .. S-1``, of one axis as a tuple."""
    if S == 2:
        return ((0.0 - f) * dx, (1.0 - f) * dx)
    if S == 3:
        return ((0.0 - f) * dx, (1.0 - f) * dx, (2.0 - f) * dx)
    return ((0.0 - f) * dx, (1.0 - f) * dx, (2.0 - f) * dx, (3.0 - f) * dx)


@njit(cache=True, inline="always")
def scaled(t, s, S):
    """``s * t`` for a tuple ``t`` of ``S`` = 2 to 4 values."""
    if S == 2:
        return (s * t[0], s * t[1])
    if S == 3:
        return (s * t[0], s * t[1], s * t[2])
    return (s * t[0], s * t[1], s * t[2], s * t[3])


@njit(cache=True, inline="always")
def cast(t, real, S):
    """A tuple ``t`` of ``S`` = 2 to 4 values converted to the scalar type ``real`` (so a float32 run's
    per-node arithmetic stays in float32)."""
    if S == 2:
        return (real(t[0]), real(t[1]))
    if S == 3:
        return (real(t[0]), real(t[1]), real(t[2]))
    return (real(t[0]), real(t[1]), real(t[2]), real(t[3]))


@njit(cache=True, inline="always")
def axis_stencil(KERNEL, x_a, origin_a, dx, inv_dx, real, S):
    r"""One axis ``a`` of a particle's transfer stencil, the set-up that P2G and G2P share: the base node
    :math:`b`, the fraction :math:`f = (x_a - o_a)/\Delta x - b`, the weights :math:`N_k` (as the kernel gives
    them), and cast to the run's scalar type ``real`` the node offsets :math:`(k - f)\Delta x`, the weight
    derivatives :math:`N'_k/\Delta x` and the weights (:func:`~mpmref.backends.pointwise.stencil.kernel_axis`)."""
    b, f, w, dw = kernel_axis(KERNEL, np.float64, (x_a - origin_a) / dx)
    return b, f, w, cast(offsets(f, dx, S), real, S), cast(scaled(dw, inv_dx, S), real, S), cast(w, real, S)
