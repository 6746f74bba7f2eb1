r"""P2G of the GPU backend (:func:`mpmref.backends.numpy.transfers.p2g` and ``p2g_fused`` for the equations).

Two kernels. ``prelude`` runs once per particle, in the order of :mod:`mpmref.backends.cuda.sort`, and writes the
particle's *row*: what every node of its stencil takes from it (:class:`Row`): its fractions :math:`f_a` (the weights
and offsets follow from them), mass :math:`m_p`, momentum :math:`m_p v_p`, affine momentum :math:`m_p C_p` (APIC,
PolyPIC, MLS-MPM) and force matrix :math:`Q_p = -V_p^0\tau_p D_p^{-1}` (MLS force) or :math:`-V_p^0\tau_p` (classic),
the Kirchhoff stress :math:`\tau_p` computed there by its material (:mod:`~mpmref.backends.cuda.materials`); and with
PolyPIC the momentum of its higher modes at each stencil node, :math:`m_p\sum_r s_r(x_i)\,c_{pr}`. A fused P2G folds the
step's force in: with the MLS force :math:`A_p = m_p C_p + \Delta t\,Q_p` takes the place of :math:`m_p C_p` (Hu et al.
2018 §4; the 88-line program's ``affine``), with the classic force :math:`\Delta t\,Q_p \nabla w_{ip}` joins the
momentum.

``gather`` runs once per node and sums, in a fixed order, what the particles of the :math:`S^d` cells whose
stencil reaches it give it: offsets in C order, and within a cell the sort's order (particle index). No float
atomics: the same bits on every run (docs/gpu.md). The opt-in ``scatter`` runs once per particle and adds its
contributions with atomic adds (the order of the additions, so the last bits, vary from run to run).
"""

from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numba import types

from ...physics.kernels import KERNELS
from ..pointwise.laws import WORK
from ..pointwise.stencil import AXIS, KERNEL_CODES, axis_basis, fraction
from .launch import array, device, device_function, kernel_set, real_types, scalar
from .materials import make_materials
from .runtime import cuda, load
from .sort import INDEX


class Row(NamedTuple):
    """The columns of a particle's row (``-1``: the row has no such columns): ``fx`` (d), ``mass`` (1),
    ``momentum`` (d), ``affine`` (d × d: :math:`m_p C_p`, or the fused :math:`A_p`), ``force`` (d × d: :math:`Q_p`,
    or the fused classic :math:`\\Delta t\\,Q_p`), ``modes`` (:math:`S^d` × d), and ``width``."""

    fx: int
    mass: int
    momentum: int
    affine: int
    force: int
    modes: int
    width: int


def row_layout(dim, support, affine, poly, mls_force, fused):
    """The :class:`Row` of a configuration: affine columns with an affine scheme or a fused MLS force, force
    columns unless the MLS force is fused into the affine ones, mode columns with PolyPIC."""
    columns, at = {}, 0
    for name, width, present in (("fx", dim, True), ("mass", 1, True), ("momentum", dim, True),
                                 ("affine", dim * dim, affine or (fused and mls_force)),
                                 ("force", dim * dim, not (fused and mls_force)),
                                 ("modes", support**dim * dim, poly)):
        columns[name] = at if present else -1
        at += width if present else 0
    return Row(width=at, **columns)


@lru_cache(maxsize=None)
def p2g_kernels(dtype, dim, kernel, affine, poly, mls_force, laws, fused):
    """The P2G kernels of one configuration (a namespace of :class:`~.launch.DeviceKernel` ``prelude``, ``gather``
    and ``scatter``, and the :class:`Row` ``row``): particles of ``dtype`` in ``dim`` dimensions, the kernel named
    ``kernel``, an ``affine`` scheme, PolyPIC's modes (``poly``), the MLS or classic force, the material laws
    ``laws`` (:func:`~mpmref.backends.pointwise.laws.laws_of`), ``fused`` or not."""
    load()
    T, nb = real_types(dtype)
    D = dim
    KERNEL, S = KERNEL_CODES[kernel], KERNELS[kernel].support
    st_fraction, st_weights, st_axis_basis = device(fraction), device(AXIS[kernel]), device(axis_basis)
    K = S**D  # nodes of a stencil
    M = K - 1 - D  # PolyPIC's higher modes
    mats = make_materials(dtype, dim, laws)
    mats_stress, mats_load_state = mats.stress, mats.load_state
    row = row_layout(D, S, affine, poly, mls_force, fused)
    FX, MASS, MOM, AFF, QF, MODES = row.fx, row.mass, row.momentum, row.affine, row.force, row.modes
    one, zero = T(1.0), T(0.0)
    MLS_FOLDED = fused and mls_force
    SUMS = 1 + 2 * D  # a node's mass, momentum and force

    @device_function
    def digits(o, out):
        """The per-axis stencil index of the ``o``-th node of a stencil (C order) into ``out``."""
        for a in range(D - 1, -1, -1):
            out[a] = o % S
            o //= S

    @device_function
    def mode_momentum(p, f, h, m, modes, mode_index, rows, k):
        r"""PolyPIC: :math:`m_p \sum_r s_r(x_i)\,c_{pr}` at each stencil node into the row's mode columns."""
        w = cuda.local.array(S, nb)
        q = cuda.local.array((D, S, S), nb)
        norm = cuda.local.array((D, S), nb)
        at = cuda.local.array(D, types.int64)
        for a in range(D):
            weights = st_weights(T, f[a])[0]
            for j in range(S):
                w[j] = weights[j]
            st_axis_basis(w, f[a], h, q[a], norm[a])
        for o in range(K):
            digits(o, at)
            for a in range(D):
                total = zero
                for r in range(M):
                    s = m
                    for c in range(D):
                        s *= q[c, mode_index[r, c], at[c]]
                    total += s * modes[p, r, a]
                rows[k, MODES + o * D + a] = total

    def prelude(order, x, v, C, modes, F, J, Jp, mass, vol0, material, rules, params, mode_index, origin, dx,
                inertia, dt, rows):
        """Row ``k`` of ``rows``: what particle ``order[k]`` gives the nodes of its stencil (the module doc)."""
        k = cuda.grid(1)
        if k >= order.shape[0]:
            return
        p = order[k]
        h = T(dx)
        f = cuda.local.array(D, nb)
        for a in range(D):
            f[a] = st_fraction(KERNEL, T, (x[p, a] - origin[a]) / h)[1]
            rows[k, FX + a] = f[a]
        m = mass[p]
        rows[k, MASS] = m
        for a in range(D):
            rows[k, MOM + a] = m * v[p, a]
        tau = cuda.local.array((D, D), nb)
        Fp = cuda.local.array((D, D), nb)
        work = cuda.local.array((WORK, D, D), nb)
        Jv, Jpv = mats_load_state(p, F, J, Jp, Fp)
        mats_stress(rules[material[p]], params[material[p]], Fp, Jv, Jpv, tau, work)
        scale = -vol0[p] / T(inertia) if mls_force else -vol0[p] * (T(dt) if fused else one)
        for a in range(D):
            for b in range(D):
                q = scale * tau[a, b]
                if AFF >= 0:
                    rows[k, AFF + a * D + b] = ((m * C[p, a, b] if affine else zero)
                                                + (T(dt) * q if MLS_FOLDED else zero))
                if QF >= 0:
                    rows[k, QF + a * D + b] = q
        if poly:
            mode_momentum(p, f, h, m, modes, mode_index, rows, k)

    @device_function
    def contribution(rows, k, at, h, out):
        r"""What row ``k`` gives the node at stencil index ``at``, into ``out``: :math:`w_{ip} m_p`, then the momentum
        :math:`w_{ip}(m_p v_p + (m_pC_p) (x_i - x_p) [+ \text{modes}])` (fused classic: plus :math:`\Delta t\,Q_p
        \nabla w_{ip}`), then the force :math:`Q_p\,w_{ip}(x_i - x_p)` (MLS) or :math:`Q_p\nabla w_{ip}` (classic)."""
        wa = cuda.local.array(D, nb)
        d = cuda.local.array(D, nb)
        g = cuda.local.array(D, nb)
        w = one
        for a in range(D):
            fa = rows[k, FX + a]
            wa[a] = st_weights(T, fa)[0][at[a]]
            d[a] = (T(at[a]) - fa) * h
            w *= wa[a]
        if QF >= 0:
            for a in range(D):
                if mls_force:
                    g[a] = w * d[a]
                else:
                    g[a] = st_weights(T, rows[k, FX + a])[1][at[a]] / h
                    for b in range(D):
                        if b != a:
                            g[a] = g[a] * wa[b]
        out[0] = w * rows[k, MASS]
        o = 0
        for a in range(D):
            o = o * S + at[a]
        for a in range(D):
            mom = rows[k, MOM + a]
            if AFF >= 0:
                for b in range(D):
                    mom += rows[k, AFF + a * D + b] * d[b]
            if MODES >= 0:
                mom += rows[k, MODES + o * D + a]
            out[1 + a] = w * mom
            if QF >= 0:
                force = zero
                for b in range(D):
                    force += rows[k, QF + a * D + b] * g[b]
                if fused:
                    out[1 + a] += force
                else:
                    out[1 + D + a] = force

    def gather(start, box, rows, node_shape, dx, mass, momentum, force):
        """Node ``i``'s mass, momentum and force (or fused momentum): the sum over the cells whose stencil reaches it
        (offsets in C order) of their particles' contributions, in the sort's order; zero outside the ``box`` of
        occupied cells (:mod:`.sort`) widened by the stencil."""
        i = cuda.grid(1)
        if i >= mass.shape[0]:
            return
        h = T(dx)
        node = cuda.local.array(D, types.int64)
        at = cuda.local.array(D, types.int64)
        total = cuda.local.array(SUMS, nb)
        part = cuda.local.array(SUMS, nb)
        rest = i
        near = True
        for a in range(D - 1, -1, -1):
            node[a] = rest % node_shape[a]
            rest //= node_shape[a]
            near = near and box[a] <= node[a] and node[a] < box[3 + a] + S
        for c in range(SUMS):
            total[c] = zero
        if near:  # the stencil's offsets in a loop of constant count, which the compiler unrolls
            for o in range(K):
                digits(o, at)
                cell = 0
                inside = True
                for a in range(D):
                    inside = inside and node[a] >= at[a]
                    cell = cell * node_shape[a] + node[a] - at[a]
                if not inside:
                    continue
                for k in range(start[cell], start[cell + 1]):
                    contribution(rows, k, at, h, part)
                    for c in range(1 + (1 if fused else 2) * D):
                        total[c] += part[c]
        mass[i] = total[0]
        for a in range(D):
            momentum[i, a] = total[1 + a]
            if not fused:
                force[i, a] = total[1 + D + a]

    def scatter(keys, rows, node_shape, dx, mass, momentum, force):
        """Row ``p``'s contributions added to the nodes of its stencil with atomic adds (the opt-in P2G; rows in the
        particles' order, ``keys`` their cells)."""
        p = cuda.grid(1)
        if p >= keys.shape[0] or keys[p] >= mass.shape[0]:
            return
        h = T(dx)
        base = cuda.local.array(D, types.int64)
        at = cuda.local.array(D, types.int64)
        part = cuda.local.array(SUMS, nb)
        rest = keys[p]
        for a in range(D - 1, -1, -1):
            base[a] = rest % node_shape[a]
            rest //= node_shape[a]
        for o in range(K):
            digits(o, at)
            node = 0
            for a in range(D):
                node = node * node_shape[a] + base[a] + at[a]
            contribution(rows, p, at, h, part)
            cuda.atomic.add(mass, node, part[0])
            for a in range(D):
                cuda.atomic.add(momentum, (node, a), part[1 + a])
                if not fused:
                    cuda.atomic.add(force, (node, a), part[1 + D + a])

    def clear(mass, momentum, force):
        """Node ``i``'s mass, momentum and force set to zero (before the atomic scatter)."""
        i = cuda.grid(1)
        if i < mass.shape[0]:
            mass[i] = zero
            for a in range(D):
                momentum[i, a] = zero
                if not fused:
                    force[i, a] = zero

    real1, real2, real3 = array(dtype, 1), array(dtype, 2), array(dtype, 3)
    ints, f64 = array(INDEX, 1), scalar(np.float64)
    shape = array(np.int64, 1)
    made = kernel_set(
        prelude=(prelude, (ints, real2, real2, real3, real3, real3, real1, real1, real1, real1, array(np.int32, 1),
                           array(np.int64, 1), array(np.float64, 2), array(np.int64, 2), real1, f64, f64, f64, real2)),
        gather=(gather, (ints, ints, real2, shape, f64, real1, real2, real2)),
        scatter=(scatter, (ints, real2, shape, f64, real1, real2, real2)),
        clear=(clear, (real1, real2, real2)))
    made.row = row
    return made
