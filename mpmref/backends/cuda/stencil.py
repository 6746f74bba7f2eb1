r"""Kernel stencils of the GPU backend, one particle and one axis at a time (numba-cuda device functions).

The B-splines of :mod:`mpmref.physics.kernels`, written with the same operations: a particle at grid coordinate
:math:`\xi = (x_p - o)/\Delta x` has the base node :math:`b = \lfloor \xi - s \rfloor` (``s`` = the kernel's
``base_shift``) and the fraction :math:`f = \xi - b`; its stencil along the axis is the nodes :math:`b + k`,
:math:`k = 0 \dots S-1`, with weights :math:`N_k(f)`, derivatives :math:`N'_k(f)` (grid units) and offsets
:math:`x_i - x_p = (k - f)\Delta x`. PolyPIC's per-axis orthogonal polynomials
(:func:`mpmref.physics.polypic.axis_basis`: the three-term recurrence, and the top polynomial in closed form) are
here too.
"""

import math
from functools import lru_cache
from math import comb, factorial
from types import SimpleNamespace

import numpy as np

from ...physics.kernels import KERNELS
from .launch import device_function
from .runtime import load


@lru_cache(maxsize=None)
def make_stencil(dtype, kernel):
    """The stencil device functions of the kernel named ``kernel`` in ``dtype``: a namespace of ``base(xi)`` (the
    base node, an int), ``weight(f, k)``, ``slope(f, k)`` (:math:`N'_k(f)`, grid units) and
    ``axis_basis(w, f, dx, q, norm)`` (PolyPIC, below), and the support ``S``."""
    load()
    T = np.dtype(dtype).type
    spec = KERNELS[kernel]
    S = spec.support
    shift = T(spec.base_shift)
    half, one, two, six = T(0.5), T(1.0), T(2.0), T(6.0)
    three_halves, three_quarters, two_thirds = T(1.5), T(0.75), T(2.0 / 3.0)
    zero = T(0.0)
    #: the (S-1)-th forward difference's coefficients and L = (S-1)! dx^(S-1) without dx (PolyPIC's top mode)
    difference = tuple(T((-1) ** (S - 1 - k) * comb(S - 1, k)) for k in range(S))
    top_factor = T(factorial(S - 1))

    @device_function
    def base(xi):
        """The lowest stencil node along an axis, :math:`\\lfloor \\xi - s \\rfloor`."""
        return int(math.floor(xi - shift))

    @device_function
    def weight(f, k):
        r""":math:`N_k(f)`: quadratic :math:`\tfrac12(\tfrac32 - f)^2, \tfrac34 - (f - 1)^2, \tfrac12(f - \tfrac12)^2`;
        cubic (:math:`a = f - 1`, :math:`b = 2 - f`) :math:`b^3/6, \tfrac12 a^3 - a^2 + \tfrac23,
        \tfrac12 b^3 - b^2 + \tfrac23, a^3/6`; linear :math:`1 - f, f`."""
        if S == 3:
            if k == 0:
                return half * ((three_halves - f) * (three_halves - f))
            if k == 1:
                return three_quarters - (f - one) * (f - one)
            return half * ((f - half) * (f - half))
        if S == 4:
            a, b = f - one, two - f
            if k == 0:
                return b * b * b / six
            if k == 1:
                return half * (a * a * a) - a * a + two_thirds
            if k == 2:
                return half * (b * b * b) - b * b + two_thirds
            return a * a * a / six
        return one - f if k == 0 else f

    @device_function
    def slope(f, k):
        r""":math:`N'_k(f)` in grid units: quadratic :math:`f - \tfrac32, -2(f - 1), f - \tfrac12`; cubic
        :math:`-\tfrac12 b^2, \tfrac32 a^2 - 2a, -\tfrac32 b^2 + 2b, \tfrac12 a^2`; linear :math:`-1, 1`."""
        if S == 3:
            if k == 0:
                return f - three_halves
            if k == 1:
                return -two * (f - one)
            return f - half
        if S == 4:
            a, b = f - one, two - f
            if k == 0:
                return -half * (b * b)
            if k == 1:
                return three_halves * (a * a) - two * a
            if k == 2:
                return -three_halves * (b * b) + two * b
            return half * (a * a)
        return -one if k == 0 else one

    @device_function
    def axis_basis(w, f, dx, q, norm):
        r"""PolyPIC's orthogonal polynomials of one axis at its stencil nodes
        (:func:`mpmref.physics.polypic.axis_basis`): ``q[j, k]`` = :math:`q_j(\delta_k)`, ``norm[j]`` =
        :math:`\langle q_j, q_j\rangle`, from the weights ``w[k]`` and the fraction ``f``: :math:`q_0 = 1`,
        :math:`q_{j+1} = (\delta - \alpha_j)q_j - \beta_j q_{j-1}` with :math:`\alpha_j = \langle\delta q_j,
        q_j\rangle/\langle q_j, q_j\rangle`, :math:`\beta_j = \langle q_j, q_j\rangle/\langle q_{j-1},
        q_{j-1}\rangle` (Gautschi 2004 §2.2.3), :math:`\delta_k = (k - f)\Delta x`; the top one
        :math:`q_{S-1} = \lambda d_k / N_k`, :math:`\lambda = L/\sum_k d_k^2/N_k`, norm :math:`\lambda L`,
        :math:`L = (S-1)!\,\Delta x^{S-1}`, all zero where a weight is 0
        (:func:`mpmref.physics.polypic.top_polynomial`)."""
        total = zero
        for k in range(S):
            q[0, k] = one
            total += w[k]
        norm[0] = total
        for j in range(S - 2):
            num = zero
            for k in range(S):
                num += w[k] * ((T(k) - f) * dx) * q[j, k] * q[j, k]
            alpha = num / norm[j] if norm[j] > zero else zero
            beta = norm[j] / norm[j - 1] if j > 0 and norm[j - 1] > zero else zero
            total = zero
            for k in range(S):
                nxt = ((T(k) - f) * dx - alpha) * q[j, k]
                if j > 0:
                    nxt -= beta * q[j - 1, k]
                q[j + 1, k] = nxt
                total += w[k] * nxt * nxt
            norm[j + 1] = total
        power = one
        for _ in range(S - 1):
            power *= dx
        L = top_factor * power
        inside = True
        total = zero
        for k in range(S):
            inside = inside and w[k] > zero
            total += difference[k] * difference[k] / w[k] if w[k] > zero else zero
        lam = L / total if inside else zero
        for k in range(S):
            q[S - 1, k] = lam * difference[k] / w[k] if inside else zero
        norm[S - 1] = lam * L

    return SimpleNamespace(S=S, base=base, weight=weight, slope=slope, axis_basis=axis_basis)
