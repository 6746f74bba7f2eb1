"""Particle sources (``[[emitters]]``): a disk (2D) or sphere (3D) of material released again and again.

Emitter ``e`` makes its ``k``-th release (``k = 0, 1, ...``) at the first synchronous step that starts at
or after :math:`t_k = t_{start} + k\\,\\Delta t_{release}`, for every :math:`t_k < t_{until}`: a copy of the
emitter's disk, sampled once like a ``disk`` body (:func:`mpmref.scene.sampling.sample_body`), with the
emitter's velocity, at rest otherwise (``F = I``, ``C = 0``, no CPIC tags). At most one release per emitter
per step (a fixed ``time.dt`` longer than the interval is refused by the scene).

The new particles get new stable ids, counted on from the largest id at the start of the run, so that ids
are never reused even after particles leave the domain. What has been released (``emitter_releases``, one
count per emitter) and the next id (``emitter_next_id``) live in the state's stepper arrays and so in every
checkpoint: a resumed run releases exactly what the uninterrupted run does.
"""

from dataclasses import replace

import numpy as np

from ..scene.sampling import make_particles, sample_body
from ..state import Particles
from ..steppers.synchronous import with_cpic_tags

RELEASES = "emitter_releases"
NEXT_ID = "emitter_next_id"
#: a release is due when the step starts within this fraction of the interval before its time (the clock is a
#: sum of steps and carries round-off)
TIME_TOLERANCE = 1e-9


def release_template(scene, emitter):
    """The particles of one release of ``emitter`` (ids ``0 .. n-1``; :func:`emit` gives them new ones)."""
    body = emitter.body
    pts, volume = sample_body(body, scene.dim, scene.grid.dx, scene.base_dir)
    n, dim = len(pts), scene.dim
    rho = scene.materials[body.material].rho
    return make_particles(scene, x=pts, v=np.broadcast_to(body.params["velocity"], pts.shape),
                          mass=np.full(n, volume * rho), vol0=np.full(n, volume),
                          material=np.full(n, list(scene.materials).index(body.material), dtype=np.int32),
                          C=np.zeros((n, dim, dim)))


def with_emitters(scene, state):
    """``state`` with the emitters' bookkeeping (no release yet; next id after the largest) where it is missing."""
    if not scene.emitters or RELEASES in state.stepper:
        return state
    next_id = int(state.particles.id.max(initial=-1)) + 1
    stepper = {**state.stepper, RELEASES: np.zeros(len(scene.emitters), dtype=np.int64),
               NEXT_ID: np.array(next_id, dtype=np.int64)}
    return replace(state, stepper=stepper)


def due(emitter, k, time):
    """Whether release ``k`` of ``emitter`` is to be made by a step starting at ``time``."""
    t_k = emitter.start + k * emitter.interval
    return t_k < emitter.until and time >= t_k - TIME_TOLERANCE * emitter.interval


def due_now(scene, state):
    """Whether a release of any emitter is due at ``state.time`` (what :func:`emit` would append something for)."""
    releases = state.stepper[RELEASES]
    return any(due(emitter, int(releases[e]), state.time) for e, emitter in enumerate(scene.emitters))


def schedule(state):
    """The emitters' bookkeeping in ``state`` (what each has released, the next id; empty without emitters): what a run
    continued from that state's particles needs to release what the scene's own run releases, and no more."""
    return {key: state.stepper[key] for key in (RELEASES, NEXT_ID) if key in state.stepper}


def released(before, after):
    """The particles that :func:`emit` appended to ``before`` (Particles) to make ``after``: its last rows."""
    return after.select(np.arange(before.n, after.n))


def emit(scene, state, templates):
    """``state`` with the releases due at ``state.time`` appended (``templates``: :func:`release_template` of
    each emitter), each with new ids; unchanged if none is due."""
    releases = state.stepper[RELEASES].copy()
    next_id = int(state.stepper[NEXT_ID])
    new = []
    for e, (emitter, template) in enumerate(zip(scene.emitters, templates)):
        if due(emitter, int(releases[e]), state.time):
            part = template.copy()
            part.id = np.arange(next_id, next_id + part.n, dtype=np.int64)
            next_id += part.n
            releases[e] += 1
            new.append(part)
    if not new:
        return state
    old = state.particles
    if old.tag_A is not None:
        new = [with_cpic_tags(p, old.tag_A.shape[1]) for p in new]
    stepper = {**state.stepper, RELEASES: releases, NEXT_ID: np.array(next_id, dtype=np.int64)}
    return replace(state, particles=Particles.concatenate([old, *new]), stepper=stepper)
