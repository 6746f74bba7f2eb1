r"""Materials of the Numba backend: each material's law run over that material's particles, in parallel.

A material declares its law next to its reference class (:class:`mpmref.physics.materials.CompiledLaw`): its pointwise
functions (:mod:`mpmref.backends.pointwise.laws`) and its parameter row. :func:`law_kernels` builds the three parallel
kernels of a law from them (stress, return map, wave speeds), one particle at a time; :func:`material_kernels` gives
them in the shape of :class:`~mpmref.backends.base.MaterialTable`. Nothing here names a material: a new one runs as
soon as it declares its law. A kernel reads each particle's parameter row from the scene's parameter table by the
particle's material index, so one call runs every material of a class
(:class:`~mpmref.backends.base.EachParticlesMaterial`).

The kernels loop over chunks of :data:`CHUNK` particles and allocate the laws' work arrays once per chunk. A law's
functions are the kernel's globals (:func:`bound`) and its digest a closure constant: Numba's disk cache keys a
closure on its constants, so each law's kernels are cached apart and recompiled when its source changes (a compiled
function as a closure constant would pickle differently in every process and defeat the cache).
"""

import types
from functools import lru_cache

import numpy as np
from numba import njit, prange

from ..base import EachParticlesMaterial
from ..pointwise.laws import WORK, functions, law_digest
from .source_digest import SOURCE_DIGEST
from .twin import parallel_kernel

#: particles per chunk of a material kernel's parallel loop (one set of work arrays per chunk)
CHUNK = 64
#: the pointwise functions of the law a kernel runs: each kernel reads its own law's (:func:`bound`)
law_stress = law_return_map = law_wave_speed = None


def bound(function, **names):
    """A copy of ``function`` that reads ``names`` as globals besides its module's (what a kernel of one law calls)."""
    return types.FunctionType(function.__code__, {**function.__globals__, **names}, function.__name__,
                              function.__defaults__, function.__closure__)


@njit(cache=True)
def n_chunks(n):
    """Number of :data:`CHUNK`-sized chunks covering ``n`` particles."""
    return (n + CHUNK - 1) // CHUNK


@njit(cache=True, inline="always")
def deformation_source(F, spare):
    """The array a chunk of particles reads its deformation gradients from: ``F``, or where the scene has none
    ``spare``, one (1, d, d) matrix (a law of :math:`J` does not read it). Chosen once per chunk: an array chosen per
    particle is reference-counted at every particle, which made the serial build of the wave-speed kernel four times
    slower than its parallel build on one thread (docs/performance.md, "An array chosen per particle")."""
    return F if F.shape[0] > 0 else spare


@njit(cache=True, inline="always")
def particle_state(F, J, Jp, p, source):
    """Particle ``p``'s deformation gradient (from ``source``, :func:`deformation_source`), volume ratio and plastic
    volume ratio (1 where the scene has none)."""
    one = source.dtype.type(1.0)
    return (source[p if F.shape[0] > 0 else 0], J[p] if J.shape[0] > 0 else one, Jp[p] if Jp.shape[0] > 0 else one)


@lru_cache(maxsize=None)
def law_kernels(law):
    """The parallel kernels of a :class:`~mpmref.physics.materials.CompiledLaw`, a namespace of

    * ``stress(F, J, Jp, idx, material, table, tau)``: the Kirchhoff stress of the particles ``idx`` into ``tau``;
    * ``return_map(F, Jp, idx, material, table)``: their plastic projection, in place (``None`` for an elastic law);
    * ``wave_speeds(F, J, Jp, idx, at, material, table, out)``: the wave speed of particle ``idx[k]`` into
      ``out[at[k]]`` (float64): ``at`` is ``idx`` for the return map's output ``wave_speed``
      (:class:`~mpmref.backends.base.MaterialTable`), positions in a compact array for :func:`wave_speeds`;
    * ``return_map_speeds(F, Jp, idx, material, table, out)``: the return map, and the wave speed of each projected
      particle ``idx[k]`` into ``out[idx[k]]`` in the same loop, the particle's new state still in cache (``None``
      for an elastic law),

    particle ``p``'s parameters the row ``table[material[p]]`` (:func:`~mpmref.backends.pointwise.laws.parameter_table`
    of the scene's materials, indexed by the particles' material indices ``material``); ``F``, ``J``, ``Jp`` with no
    rows where the scene has none.
    """
    found = functions(law)
    LAW, SOURCES = law_digest(law), SOURCE_DIGEST

    def stress(F, J, Jp, idx, material, table, tau):
        LAW, SOURCES  # noqa: B018 - closure constants: the cache key (module doc)
        n = idx.shape[0]
        d = tau.shape[1]
        for chunk in prange(n_chunks(n)):
            work = np.empty((WORK, d, d), tau.dtype)
            source = deformation_source(F, np.empty((1, d, d), tau.dtype))
            for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
                p = idx[k]
                Fp, Jv, Jpv = particle_state(F, J, Jp, p, source)
                law_stress(table[material[p]], Fp, Jv, Jpv, tau[p], work)

    def return_map(F, Jp, idx, material, table):
        LAW, SOURCES  # noqa: B018
        n = idx.shape[0]
        for chunk in prange(n_chunks(n)):
            work = np.empty((WORK, F.shape[1], F.shape[1]), F.dtype)
            for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
                p = idx[k]
                Jp[p] = law_return_map(table[material[p]], F[p], Jp[p], work)

    def wave_speeds(F, J, Jp, idx, at, material, table, out):
        LAW, SOURCES  # noqa: B018
        n = idx.shape[0]
        d = F.shape[1]
        for chunk in prange(n_chunks(n)):
            source = deformation_source(F, np.ones((1, d, d), J.dtype))
            for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
                p = idx[k]
                Fp, Jv, Jpv = particle_state(F, J, Jp, p, source)
                out[at[k]] = law_wave_speed(table[material[p]], Fp, Jv, Jpv)

    def return_map_speeds(F, Jp, idx, material, table, out):
        LAW, SOURCES  # noqa: B018
        n = idx.shape[0]
        one = F.dtype.type(1.0)
        for chunk in prange(n_chunks(n)):
            work = np.empty((WORK, F.shape[1], F.shape[1]), F.dtype)
            for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
                p = idx[k]
                prm = table[material[p]]
                Jp[p] = law_return_map(prm, F[p], Jp[p], work)
                out[p] = law_wave_speed(prm, F[p], one, Jp[p])

    def compiled(kernel):
        return parallel_kernel(cache=True)(bound(kernel, law_stress=found.stress, law_wave_speed=found.wave_speed,
                                                     law_return_map=found.return_map))

    plastic = found.return_map is not None
    return types.SimpleNamespace(stress=compiled(stress), wave_speeds=compiled(wave_speeds),
                                 return_map=compiled(return_map) if plastic else None,
                                 return_map_speeds=compiled(return_map_speeds) if plastic else None)


def _or_empty(array, dtype, *shape):
    return array if array is not None else np.empty(shape, dtype=dtype)


def particle_arrays(particles):
    """``(F, J, Jp)`` of ``particles`` as the kernels take them (empty arrays for the fields the scene has not)."""
    n, d = particles.x.shape
    dtype = particles.x.dtype
    return (_or_empty(particles.F, dtype, 0, d, d), _or_empty(particles.J, dtype, 0),
            _or_empty(particles.Jp, dtype, 0))


def material_kernels(materials, table):
    """``{material class: (stress, return_map, wave_speed)}`` for a :class:`~mpmref.backends.base.MaterialTable` of
    ``materials`` (the scene's, in order), from each class's declared law; each entry an
    :class:`~mpmref.backends.base.EachParticlesMaterial`: its kernels take the particles' material indices as
    ``material`` and read each particle's row of ``table``, the parameter table of ``materials``
    (:func:`~mpmref.backends.pointwise.laws.parameter_table`). Given the output ``wave_speed``, a
    plastic law's return map writes each particle's wave speed in the loop that projects it (``return_map_speeds`` of
    :func:`law_kernels`)."""
    out = {}
    for cls in {type(m) for m in materials}:
        kernels = law_kernels(cls.compiled)

        def stress(material, particles, idx, tau, kernels=kernels):
            kernels.stress(*particle_arrays(particles), idx, material, table, tau)

        def return_map(material, F, Jp, idx, wave_speed=None, kernels=kernels):
            if wave_speed is None:
                kernels.return_map(F, Jp, idx, material, table)
            else:
                kernels.return_map_speeds(F, Jp, idx, material, table, wave_speed)

        def wave_speed(material, F, J, Jp, idx, out, kernels=kernels):
            dtype = F.dtype if F is not None else J.dtype
            d = F.shape[1] if F is not None else 1
            kernels.wave_speeds(_or_empty(F, dtype, 0, d, d), _or_empty(J, dtype, 0), _or_empty(Jp, dtype, 0), idx, idx,
                                material, table, out)

        out[cls] = EachParticlesMaterial((stress, return_map if kernels.return_map is not None else None, wave_speed))
    return out


def wave_speeds(table, parameters, particles, idx):
    """The current wave speed (float64) of the particles ``idx``, each by its material's law, through the
    :class:`~mpmref.backends.base.MaterialTable` ``table``'s calls; ``parameters`` the parameter table of its
    materials."""
    out = np.empty(idx.size)
    arrays = particle_arrays(particles)
    of_idx = table.call_of[particles.material[idx]] if len(table.calls) > 1 else None
    for c, (material, _, _) in enumerate(table.calls):
        where = np.flatnonzero(of_idx == c) if of_idx is not None else np.arange(idx.size)
        if where.size:
            law_kernels(type(material).compiled).wave_speeds(*arrays, idx[where], where, particles.material,
                                                             parameters, out)
    return out
