r"""Per-particle kernels of the GPU backend besides the transfers: the stress stage, the return map, and the summary
of a state that a run checks every step (:mod:`mpmref.backends.residency`).

The material laws are those of :mod:`mpmref.backends.cuda.materials`. The summary is a reduction over the particles
in two levels, a tree in each block's shared memory then one atomic maximum per block and quantity: a maximum is
exact whatever the order, so the summary is the same on every run.
"""

import math
from functools import lru_cache

import numpy as np
from numba import types

from ...state import EVOLVING_FIELDS
from ..pointwise.laws import WORK
from .launch import BLOCK, array, device_function, kernel_set, real_types
from .materials import make_materials
from .runtime import cuda, load

#: the particle fields whose non-finite values the summary flags, in the order of its first entries: every field that
#: a step evolves (:data:`mpmref.state.EVOLVING_FIELDS`), which ``summarize`` takes and flags in this order
CHECKED_FIELDS = EVOLVING_FIELDS


def summary_size(dim):
    """Entries of a summary: a flag per field of :data:`CHECKED_FIELDS`, the negated smallest and the largest
    coordinate per axis, the largest velocity change and the largest signal speed."""
    return len(CHECKED_FIELDS) + 2 * dim + 2


@lru_cache(maxsize=None)
def particle_kernels(dtype, dim, laws):
    """The kernels ``stress``, ``return_map``, ``wave_speeds`` and ``summarize`` for particles of ``dtype`` in ``dim``
    dimensions with the material laws ``laws`` (a namespace of :class:`~.launch.DeviceKernel`)."""
    load()
    _, nb = real_types(dtype)
    D = dim
    mats = make_materials(dtype, dim, laws)
    mats_stress, mats_return_map, mats_wave_speed = mats.stress, mats.return_map, mats.wave_speed
    load_state = mats.load_state
    NQ = summary_size(dim)
    FLAGS = len(CHECKED_FIELDS)

    def stress(F, J, Jp, material, rules, params, tau):
        """``tau[p]``: particle ``p``'s Kirchhoff stress by its material's law."""
        p = cuda.grid(1)
        if p >= material.shape[0]:
            return
        Fp = cuda.local.array((D, D), nb)
        out = cuda.local.array((D, D), nb)
        work = cuda.local.array((WORK, D, D), nb)
        Jv, Jpv = load_state(p, F, J, Jp, Fp)
        mats_stress(rules[material[p]], params[material[p]], Fp, Jv, Jpv, out, work)
        for a in range(D):
            for b in range(D):
                tau[p, a, b] = out[a, b]

    def return_map(F, Jp, material, rules, params, F_out, Jp_out):
        """``F_out[p]``, ``Jp_out[p]``: particle ``p``'s plastic projection (a copy for elastic laws)."""
        p = cuda.grid(1)
        if p >= material.shape[0]:
            return
        Fp = cuda.local.array((D, D), nb)
        work = cuda.local.array((WORK, D, D), nb)
        for a in range(D):
            for b in range(D):
                Fp[a, b] = F[p, a, b]
        Jp_out[p] = mats_return_map(rules[material[p]], params[material[p]], Fp, Jp[p], work)
        for a in range(D):
            for b in range(D):
                F_out[p, a, b] = Fp[a, b]

    def wave_speeds(F, J, Jp, material, rules, params, out):
        """``out[p]``: particle ``p``'s wave speed :math:`c_p` in its current state, by its material's law (float64;
        the return map's output ``wave_speed``)."""
        p = cuda.grid(1)
        if p >= material.shape[0]:
            return
        Fp = cuda.local.array((D, D), nb)
        Jv, Jpv = load_state(p, F, J, Jp, Fp)
        out[p] = mats_wave_speed(rules[material[p]], params[material[p]], Fp, Jv, Jpv)

    @device_function
    def finite(value):
        """Whether ``value`` is neither infinite nor NaN."""
        return not (math.isinf(value) or math.isnan(value))

    @device_function
    def finite_1(values, p):
        """Whether ``values[p]`` of a 1-dimensional array (no rows: true) is finite."""
        return values.shape[0] == 0 or finite(values[p])

    @device_function
    def finite_2(values, p):
        """Whether every entry of row ``p`` of a 2-dimensional array (no rows: true) is finite."""
        ok = True
        if values.shape[0] > 0:
            for i in range(values.shape[1]):
                ok = ok and finite(values[p, i])
        return ok

    @device_function
    def finite_3(values, p):
        """Whether every entry of row ``p`` of a 3-dimensional array (no rows: true) is finite."""
        ok = True
        if values.shape[0] > 0:
            for i in range(values.shape[1]):
                for j in range(values.shape[2]):
                    ok = ok and finite(values[p, i, j])
        return ok

    def summarize(x, v, v_old, C, F, J, Jp, modes, material, rules, params, out):
        """The maxima of :func:`summary_size`'s quantities over the particles, into ``out`` (set to -inf before)."""
        shared = cuda.shared.array((NQ, BLOCK), types.float64)
        t = cuda.threadIdx.x
        p = cuda.grid(1)
        for q in range(NQ):
            shared[q, t] = -math.inf
        if p < x.shape[0]:
            flags = (finite_2(x, p), finite_2(v, p), finite_3(C, p), finite_3(F, p), finite_1(J, p), finite_1(Jp, p),
                     finite_3(modes, p))
            for q in range(FLAGS):
                shared[q, t] = 0.0 if flags[q] else 1.0
            speed2 = 0.0
            change = 0.0
            for a in range(D):
                xa, va = float(x[p, a]), float(v[p, a])
                if finite(xa):
                    shared[FLAGS + a, t] = -xa
                    shared[FLAGS + D + a, t] = xa
                speed2 += va * va
                dv = abs(va - float(v_old[p, a]))
                change = dv if dv > change else change
            Fp = cuda.local.array((D, D), nb)
            Jv, Jpv = load_state(p, F, J, Jp, Fp)
            signal = mats_wave_speed(rules[material[p]], params[material[p]], Fp, Jv, Jpv) + math.sqrt(speed2)
            shared[FLAGS + 2 * D, t] = change if finite(change) else -math.inf
            shared[FLAGS + 2 * D + 1, t] = signal if finite(signal) else -math.inf
        cuda.syncthreads()
        step = BLOCK // 2
        while step > 0:
            if t < step:
                for q in range(NQ):
                    other = shared[q, t + step]
                    if other > shared[q, t]:
                        shared[q, t] = other
            cuda.syncthreads()
            step //= 2
        if t == 0:
            for q in range(NQ):
                cuda.atomic.max(out, q, shared[q, 0])

    real1, real2, real3 = array(dtype, 1), array(dtype, 2), array(dtype, 3)
    materials = (array(np.int32, 1), array(np.int64, 1), array(np.float64, 2))
    return kernel_set(
        stress=(stress, (real3, real1, real1) + materials + (real3,)),
        return_map=(return_map, (real3, real1) + materials + (real3, real1)),
        wave_speeds=(wave_speeds, (real3, real1, real1) + materials + (array(np.float64, 1),)),
        summarize=(summarize, (real2, real2, real2, real3, real3, real1, real1, real3) + materials
                   + (array(np.float64, 1),)))
