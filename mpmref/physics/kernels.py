"""B-spline interpolation kernels on a regular grid.

Grid node ``i`` sits at ``origin + i * dx``. A kernel with support of ``S`` nodes per axis touches the
nodes ``base + k`` (``k = 0 .. S-1``) of a particle, where ``base`` depends on the particle's grid
coordinate ``xi = (x_p - origin) / dx``. Weights are tensor products ``w_ip = prod_a N(xi_a - i_a)``.
"""

from dataclasses import dataclass
from functools import lru_cache
from itertools import product

import numpy as np


@dataclass(frozen=True)
class QuadraticBSpline:
    r"""Quadratic B-spline kernel (support 3 nodes per axis).

    .. math::

        N(x) = \begin{cases} \tfrac34 - |x|^2 & |x| < \tfrac12 \\
               \tfrac12 (\tfrac32 - |x|)^2 & \tfrac12 \le |x| < \tfrac32 \\ 0 & \text{otherwise}\end{cases}

    Source: Steffen, Kirby & Berzins 2008 §3 (quadratic B-spline MPM); used by Hu et al. 2018 §5 and the
    88-line programs. With this kernel the APIC inertia tensor is constant, :math:`D_p = \tfrac14 \Delta x^2 I` (Jiang
    et al. 2015 §5.3), which is ``inertia_factor``.
    """

    name: str = "quadratic"
    #: the base node is ``floor(xi - base_shift)`` (what compiled code uses in place of :meth:`base_node`)
    base_shift: float = 0.5
    support: int = 3
    inertia_factor: float = 0.25
    #: particles must satisfy ``low_margin <= xi < n_cells - high_margin`` so the stencil fits
    low_margin: float = 0.5
    high_margin: float = 0.5

    def base_node(self, xi):
        """Lowest stencil node index per axis: ``floor(xi - 1/2)``."""
        return np.floor(xi - 0.5).astype(np.int64)

    def weights(self, fx):
        r"""Per-axis weights and derivatives for offsets ``fx = xi - base`` (in [0.5, 1.5)).

        Returns ``w, dw`` of shape ``(n, d, 3)``; ``dw`` is :math:`dN/dx` in grid units (divide by
        :math:`\Delta x` for physical units).

        Docs: docs/mpm_cycle.md#interpolation-kernels
        """
        w = np.stack([0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2], axis=-1)
        dw = np.stack([fx - 1.5, -2.0 * (fx - 1.0), fx - 0.5], axis=-1)
        return w, dw


@dataclass(frozen=True)
class CubicBSpline:
    r"""Cubic B-spline kernel (support 4 nodes per axis).

    .. math::

        N(x) = \begin{cases} \tfrac12 |x|^3 - |x|^2 + \tfrac23 & |x| < 1 \\
               \tfrac16 (2 - |x|)^3 & 1 \le |x| < 2 \\ 0 & \text{otherwise}\end{cases}

    Source: Steffen, Kirby & Berzins 2008 §3; the kernel of Stomakhin et al. 2013 §4. Jiang et al. 2015
    §5.3 give :math:`D_p = \tfrac13 \Delta x^2 I` (``inertia_factor``).
    """

    name: str = "cubic"
    #: the base node is ``floor(xi - base_shift)`` (what compiled code uses in place of :meth:`base_node`)
    base_shift: float = 1.0
    support: int = 4
    inertia_factor: float = 1.0 / 3.0
    low_margin: float = 1.0
    high_margin: float = 1.0

    def base_node(self, xi):
        """Lowest stencil node index per axis: ``floor(xi) - 1``."""
        return np.floor(xi).astype(np.int64) - 1

    def weights(self, fx):
        """Per-axis weights and derivatives (grid units) for offsets ``fx = xi - base`` in [1, 2)."""
        a, b = fx - 1.0, 2.0 - fx  # distances to the two middle nodes
        # cubes as products, not ``**3``: NumPy's power may use a SIMD pow that differs from libm by an ulp,
        # and PolyPIC's cubic modes amplify an ulp in a near-zero weight a billionfold (docs/conformance.md)
        a3, b3 = a * a * a, b * b * b
        w = np.stack([b3 / 6.0, 0.5 * a3 - a * a + 2.0 / 3.0, 0.5 * b3 - b * b + 2.0 / 3.0, a3 / 6.0], axis=-1)
        dw = np.stack([-0.5 * b**2, 1.5 * a**2 - 2.0 * a, -1.5 * b**2 + 2.0 * b, 0.5 * a**2], axis=-1)
        return w, dw


@dataclass(frozen=True)
class LinearHat:
    r"""Linear hat kernel (support 2 nodes per axis), :math:`N(x) = \max(0, 1 - |x|)`.

    For teaching and to show grid-crossing error (Bardenhagen & Kober 2004 §2): its gradient jumps
    when a particle crosses a node. Its inertia :math:`D_p = f(1-f)\Delta x^2` varies and vanishes on
    nodes, so it serves only schemes without an affine matrix and with the classic force
    (``inertia_factor`` is ``None``).
    """

    name: str = "linear"
    #: the base node is ``floor(xi - base_shift)`` (what compiled code uses in place of :meth:`base_node`)
    base_shift: float = 0.0
    support: int = 2
    inertia_factor: float = None
    low_margin: float = 0.0
    high_margin: float = 0.0

    def base_node(self, xi):
        return np.floor(xi).astype(np.int64)

    def weights(self, fx):
        """Weights ``1 - fx, fx`` and derivatives ``-1, 1`` (grid units) for ``fx`` in [0, 1)."""
        w = np.stack([1.0 - fx, fx], axis=-1)
        dw = np.stack([-np.ones_like(fx), np.ones_like(fx)], axis=-1)
        return w, dw


KERNELS = {"quadratic": QuadraticBSpline(), "cubic": CubicBSpline(), "linear": LinearHat()}


def get_kernel(name):
    """Return the kernel registered under ``name`` (see ``KERNELS``)."""
    return KERNELS[name]


@lru_cache(maxsize=None)
def stencil_offsets(dim, support):
    """All ``support**dim`` integer offsets of a stencil, shape ``(support**dim, dim)``."""
    return np.array(list(product(range(support), repeat=dim)), dtype=np.int64)


@dataclass
class Stencil:
    """Everything a transfer needs about the particle-grid coupling of one set of particles.

    Attributes
    ----------
    base : (n, d) int array      lowest node of each particle's stencil
    fx : (n, d) float array      ``xi - base``, the particle's offset from that node in cells
    w, dw : (n, d, S) arrays     per-axis weights and their derivative (grid units)
    dx : float                   grid spacing
    inertia : float or None      :math:`D_p / I`, the APIC inertia scalar (``inertia_factor * dx**2``)
    """

    base: np.ndarray
    fx: np.ndarray
    w: np.ndarray
    dw: np.ndarray
    dx: float
    inertia: float

    @property
    def offsets(self):
        return stencil_offsets(self.base.shape[1], self.w.shape[2])

    def node_weight(self, offset):
        r"""Weight :math:`w_{ip} = \prod_a N_a` of every particle to the node ``base + offset``.

        Docs: docs/mls_vs_classic.md#from-mls-shape-functions-to-the-mls-mpm-step,
        docs/mpm_cycle.md#interpolation-kernels
        """
        d = len(offset)
        out = self.w[:, 0, offset[0]].copy()
        for a in range(1, d):
            out *= self.w[:, a, offset[a]]
        return out

    def node_gradient(self, offset):
        r"""Gradient :math:`\nabla w_{ip}` (physical units) to the node ``base + offset``, shape (n, d).

        Docs: docs/mpm_cycle.md#interpolation-kernels
        """
        d = len(offset)
        grad = np.empty(self.fx.shape, dtype=self.w.dtype)
        for a in range(d):
            g = self.dw[:, a, offset[a]] / self.dx
            for b in range(d):
                if b != a:
                    g = g * self.w[:, b, offset[b]]
            grad[:, a] = g
        return grad

    def node_offset_vector(self, offset):
        r"""Vector :math:`x_i - x_p` (physical units) to the node ``base + offset``, shape (n, d)."""
        return (np.asarray(offset, dtype=self.fx.dtype) - self.fx) * self.dx

    def node_weights(self):
        r""":meth:`node_weight` to every node of the stencil at once, shape (K, n) for the K :attr:`offsets`
        (the same products in the same order, so the same bits)."""
        offsets = self.offsets
        out = self.w[:, 0, offsets[:, 0]].T.copy()
        for a in range(1, offsets.shape[1]):
            out *= self.w[:, a, offsets[:, a]].T
        return out

    def node_offset_vectors(self):
        r""":meth:`node_offset_vector` to every node of the stencil at once, shape (K, n, d)."""
        return (self.offsets[:, None, :].astype(self.fx.dtype) - self.fx) * self.dx


def compute_stencil(kernel, x, origin, dx):
    """Evaluate ``kernel`` for particle positions ``x`` (n, d) on the grid (origin, dx).

    Docs: docs/mpm_cycle.md#interpolation-kernels
    """
    dtype = x.dtype.type
    xi = (x - np.asarray(origin, dtype=x.dtype)) / dtype(dx)
    base = kernel.base_node(xi)
    fx = xi - base
    w, dw = kernel.weights(fx)
    inertia = None if kernel.inertia_factor is None else dtype(kernel.inertia_factor * dx * dx)
    return Stencil(base=base, fx=fx, w=w, dw=dw, dx=dtype(dx), inertia=inertia)
