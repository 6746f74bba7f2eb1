"""The simulations of the CPIC case (:mod:`verification.cpic`) and what each measures.

:func:`run_watching` runs a scene and counts the particles that cross its bodies; the functions after it run
one scene each and return what it measures (:mod:`verification.cpic.results`). :func:`parts` lists the case's
independent simulations and :func:`run` runs them through an :class:`~verification.framework.executor.Executor`.
"""

from dataclasses import replace
from functools import partial

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from mpmref import Simulation
from mpmref.rigid.dynamics import current_shapes
from mpmref.rigid.polyline import distance_to_polyline, inside_closed, segment_frame, validate_polyline
from mpmref.rigid.trimesh import TriMesh, triangle_frame
from mpmref.scene.sampling import sample_particles

from ..framework.executor import Executor
from ..framework.recording import record
from ..framework.report import snapshot
from .results import Baseline, Collision, CpicResult, Cut, Sliding, Watched, Wheel
from .scenes import (
    BASELINES,
    BLADE,
    Params,
    ball_scene,
    baseline_particles,
    baseline_scene,
    cut3d_scene,
    cut_scene,
    drop_scene,
    friction_scene,
    impact_scene,
    rotor_scene,
    sand_scene,
    wheel_omega_floor,
    wheel_scene,
)

#: the outputs (names of ``[output] fields``) that the VTK frames of the CPIC case's runs record
CPIC_FRAME_OUTPUTS = ("velocity", "material")


def segment_offsets(sim, shapes=None):
    """Edge parameter ``s`` and signed offset ``h`` of every particle from every segment of every body
    (or of the polylines ``shapes``). Returns a list over segments of ``(s, h)`` arrays in particle-id
    order, and the ids."""
    order = np.argsort(sim.id)
    x = sim.x[order]
    out = []
    for shape in shapes or current_shapes(sim.scene.rigid_bodies, sim.state.rigid):
        if isinstance(shape, TriMesh):
            out += triangle_offsets(shape, x)
            continue
        for k in range(len(shape.segments)):
            out.append(segment_frame(shape, np.full(len(x), k), x))
    return out, sim.id[order]


def triangle_offsets(mesh, x):
    """Per triangle of ``mesh``: ``(s, h)`` with ``s`` the smallest barycentric coordinate of the projection of
    ``x`` (in [0, 1] iff it lies on the triangle, as a segment's edge parameter) and ``h`` the signed offset."""
    out = []
    for k in range(len(mesh.triangles)):
        bary, h = triangle_frame(mesh, np.full(len(x), k), x)
        out.append((bary.min(axis=1), h))
    return out


def count_crossings(before, after):
    """Particles (by id) whose offset from a segment's line changed sign while they projected onto it."""
    (prev, ids0), (curr, ids1) = before, after
    common, i0, i1 = np.intersect1d(ids0, ids1, return_indices=True)
    crossed = np.zeros(len(common), dtype=bool)
    for (s0, h0), (s1, h1) in zip(prev, curr):
        on = (s0[i0] >= 0) & (s0[i0] <= 1) & (s1[i1] >= 0) & (s1[i1] <= 1)
        crossed |= on & (np.sign(h0[i0]) != np.sign(h1[i1]))
    return set(common[crossed].tolist())


def run_watching(scene, frames, every_step=None, particles=None, shapes=None, backend="numpy"):
    """Run ``scene`` (from ``particles`` if given) to its end, counting crossings of its bodies (or of the
    fixed polylines ``shapes``) every step; ``every_step(sim)`` is called after each step. Returns the simulation at
    the end and its :class:`~verification.cpic.results.Watched` record."""
    sim = Simulation(scene, backend=backend, particles=particles)
    crossed, first, last = set(), None, None  # the segment offsets of the first and of the latest state

    def watch(sim):
        nonlocal first, last
        new = segment_offsets(sim, shapes)
        if first is None:
            first = new
        else:
            crossed.update(count_crossings(last, new))
            if every_step is not None:
                every_step(sim)
        last = new

    run = record(sim, watch, frames, t_end=scene.time.t_end, frame=partial(snapshot, fields=CPIC_FRAME_OUTPUTS))
    return sim, Watched(crossings=len(crossed), far_side=len(count_crossings(first, last)), frames=run.frames,
                        n_particles=sim.n_particles, steps=sim.step_count,
                        bodies=shapes or current_shapes(scene.rigid_bodies, sim.state.rigid))


def components(x, link):
    """Number of connected components of particles ``x`` linked when closer than ``link``."""
    pairs = cKDTree(x).query_pairs(link, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(x), len(x)))
    return int(connected_components(graph, directed=False)[0])


def watch(params, make_scene, **scene_kwargs):
    """The crossings record of :func:`run_watching` for ``make_scene(params, **scene_kwargs)``."""
    return run_watching(make_scene(params, **scene_kwargs), params.frames, backend=params.backend)[1]


def extended(watched, record, **measured):
    """The record of class ``record`` (a subclass of :class:`~verification.cpic.results.Watched`): ``watched`` and
    what the run ``measured`` besides."""
    return record(**vars(watched), **measured)


def momentum_run(params, exact, ghost_force=True):
    """The ball-plate collision; the drift of particles + plate momentum relative to :math:`m_{ball}|v|`."""
    scene = ball_scene(params, exact, ghost_force)
    history = []

    def record(sim):
        d = sim.diagnostics()
        history.append((sim.time, *((sim.mass[:, None] * sim.v).sum(axis=0)), d["rigid_momentum_x"],
                        d["rigid_momentum_y"], d["rigid0_vy"], d["kinetic"] + d["elastic"],
                        0.5 * scene.rigid_bodies[0].mass * (d["rigid0_vx"] ** 2 + d["rigid0_vy"] ** 2)))

    sim0 = Simulation(scene, backend=params.backend)
    p0 = (sim0.mass[:, None] * sim0.v).sum(axis=0)
    scale = float(np.linalg.norm(p0))
    sim, watched = run_watching(scene, params.frames, record, backend=params.backend)
    h = np.array(history)
    total = h[:, 1:3] + h[:, 3:5]
    return extended(watched, Collision, drift=float(np.max(np.linalg.norm(total - p0, axis=1)) / scale), history=h,
                    plate_v=float(h[-1, 5]), ball_v=float(h[-1, 2] / sim.mass.sum()), p0=scale,
                    energy0=float(h[0, 6] + h[0, 7]), energy_end=float(h[-1, 6] + h[-1, 7]))


def cutting(params):
    """The 2D cut: crossings of the wedge blade over the run and connected components at the end."""
    sim, watched = run_watching(cut_scene(params), params.frames, backend=params.backend)
    return extended(watched, Cut, components=components(sim.x, 1.0 / params.cells))


def cutting3d(params):
    """The 3D cut: crossings of the blades over the run and connected components at the end."""
    sim, watched = run_watching(cut3d_scene(params), params.frames, backend=params.backend)
    return extended(watched, Cut, components=components(sim.x, 1.0 / params.cut3d_cells))


def friction(params, ghost_force=True):
    """The block's centre-of-mass travel until it stops (v_com below 1 % of the initial speed)."""
    com = []

    def record(sim):
        m = sim.mass
        com.append((sim.time, *(m @ sim.x / m.sum()), *(m @ sim.v / m.sum())))

    scene = friction_scene(params, ghost_force)
    sim0 = Simulation(scene, backend=params.backend)
    x0 = sim0.mass @ sim0.x[:, 0] / sim0.mass.sum()
    sim, watched = run_watching(scene, params.frames, record, backend=params.backend)
    c = np.array(com)
    stopped = np.nonzero(c[:, 3] < 0.01)[0]
    return extended(watched, Sliding, com=c, stop_time=float(c[stopped[0], 0]) if stopped.size else float("nan"),
                    distance=float(c[stopped[0], 1] - x0) if stopped.size else float(c[-1, 1] - x0),
                    stopped=bool(stopped.size), expected=1.0 / (2.0 * params.mu * params.g))


def sand_wheel(params):
    """The sand wheel run: its angular velocity, the sand inside the ring and how deep inside (in Δx, from the ring's
    polygon), every step, and for each particle that entered the ring its distance (in Δx) to the nearest blade
    when it was first found inside."""
    scene = wheel_scene(params)
    history, entries = [], {}

    def record(sim):
        ring, blades = current_shapes(scene.rigid_bodies, sim.state.rigid)[:2]
        inside = np.nonzero(inside_closed(ring, sim.x))[0]
        for p in inside[~np.isin(sim.id[inside], list(entries))]:
            entries[int(sim.id[p])] = float(distance_to_polyline(blades, sim.x[p:p + 1])[0]) / scene.grid.dx
        depth = distance_to_polyline(ring, sim.x[inside]).max(initial=0.0) / scene.grid.dx
        history.append((sim.time, sim.state.rigid.angular_velocity[0], inside.size, sim.n_particles, depth))

    _, watched = run_watching(scene, params.frames, record, backend=params.backend)
    h = np.array(history)
    late = h[:, 0] >= 0.5 * params.wheel_t_end
    sign = np.sign(h[-1, 1])
    return extended(watched, Wheel, history=h, inside_max=int(h[:, 2].max()), floor=wheel_omega_floor(scene),
                    late_min=float(np.min(sign * h[late, 1])), omega_end=float(h[-1, 1]), entered=len(entries),
                    entry_blade_distance=max(entries.values(), default=0.0), depth_max=float(h[:, 4].max()),
                    t_end=params.wheel_t_end)


def baseline(params, kind, width=0.0):
    """Particles crossing the cut line, mass lost and connected components of one baseline run."""
    scene = baseline_scene(params, kind)
    full_mass = sample_particles(scene).mass.sum()
    line = [validate_polyline(BLADE, [[0, 1]])]
    sim, watched = run_watching(scene, params.frames, particles=baseline_particles(scene, kind, width), shapes=line,
                                backend=params.backend)
    return extended(watched, Baseline, components=components(sim.x, 1.0 / params.cells), kind=kind, width=width,
                    mass_lost=float(1.0 - sim.mass.sum() / full_mass))


#: the keys of the baselines in :func:`parts` start with it
BASELINE_KEY = "baseline/"


def parts(params):
    """``{key: (function, args)}``: the case's independent simulations, each a call ``function(params, *args)``
    returning its record; the longest first (they run through an :class:`~verification.framework.executor.Executor`).
    The keys are the fields of :class:`~verification.cpic.results.CpicResult`, the baselines' apart (its
    ``baselines``)."""
    jobs = {"wheel": (sand_wheel, ()), "drop": (watch, (drop_scene,)), "cut": (cutting, ()),
            "exact": (momentum_run, (True,)), "default": (momentum_run, (False,)), "impact": (watch, (impact_scene,)),
            "friction": (friction, ()), "cut3d": (cutting3d, ()), "sand": (watch, (sand_scene,))}
    if params.extended:
        jobs.update({"exact_reference": (momentum_run, (True, False)), "friction_reference": (friction, (False,)),
                     "rotor": (watch, (rotor_scene,)), "sand_2e4": (_sand_2e4, ())})
        jobs.update({f"{BASELINE_KEY}{kind}/{width}": (baseline, (kind, width)) for kind, width in BASELINES})
    return jobs


def _sand_2e4(params):
    """The blade through sand with the reference's default pushing force, for comparison."""
    return watch(params, sand_scene, pushing_force=2e4)


def run_part(job):
    """``function(params, *args)`` of one entry of :func:`parts` (module level: picklable for the executor)."""
    function, params, args = job
    return function(params, *args)


def run(params=Params(), backend="numpy", executor=None):
    """Every part of the case, every simulation on ``backend``, the independent runs through ``executor``
    (default: in this process). Returns a :class:`~verification.cpic.results.CpicResult`."""
    params = replace(params, backend=backend)
    jobs = parts(params)
    done = dict(zip(jobs, (executor or Executor(workers=1)).map(
        run_part, [(function, params, args) for function, args in jobs.values()])))
    baselines = tuple(done.pop(key) for key in jobs if key.startswith(BASELINE_KEY))
    return CpicResult(params=params, backend=backend, baselines=baselines, **done)

