"""The runs of the energy-ledger case: the examples (and the jelly under every scheme), the friction block, the
integration error's order, and the candidate's ledger booked beside the reference's.

Each example runs from its TOML file (``examples/``) with the ledger on (``[output] energy_ledger``), its grid
coarsened by ``Params.coarsen``, the free flight before its first contact skipped (:func:`free_flight`) and cut to
its run's span (:func:`span`). A run records the time and the cumulative ledger after every step, the diagnostics'
energies at its frames, each particle's cumulative share of the per-particle terms
(:data:`mpmref.observe.ledger.PER_PARTICLE`) for the VTK frames; from its states half-way and at the end, a compared run
books one step on the reference and on the candidate (:func:`compare`).
"""

import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from time import perf_counter

import numpy as np

from mpmref import Scene, SceneBuilder, Simulation
from mpmref.backends import make_backend
from mpmref.conformance.report import compare_outputs
from mpmref.conformance.stages import ledger_step
from mpmref.observe.ledger import ASYNC_COLUMNS, ASYNC_TERMS, energy_scale
from mpmref.rigid import dynamics as rigid_dynamics

from .. import energy
from ..framework.applicable import Allow, fit
from ..framework.recording import record
from ..framework.report import snapshot
from ..momentum import VARIANT, VARIANTS

EXAMPLES = Path(__file__).resolve().parent.parent.parent / "examples"


@dataclass(frozen=True)
class Run:
    """One run of the case: an example scene, under its own method or one of the compared schemes.

    Attributes
    ----------
    key : str          the run's name in tables, checks and folders
    example : str      the scene file ``examples/<example>.toml``
    variant : str      a key of :data:`verification.momentum.VARIANT` (its ``method`` replaces the example's), or
                       ``None`` for the example's own method
    head_start : float seconds of the bodies' free flight skipped before the run starts (:func:`free_flight`)
    duration : float   simulated seconds of the quick preset after that (the others multiply it)
    """

    key: str
    example: str
    variant: str | None = None
    head_start: float = 0.0
    duration: float = 0.0


#: every run of the case: the jelly under each compared scheme (its floor contact, about 100 steps in the quick
#: preset), then each example under its own method, the asynchronous stork among them: the case reads its ledger
#: at the steps the simulation reports, for asynchronous stepping its synchronised times.
RUNS = (
    *(Run(f"jelly-{v.key}", "jelly", v.key, head_start=0.265, duration=0.02) for v in VARIANTS),
    Run("snow88", "snow88", head_start=0.065, duration=0.015),
    Run("sand", "sand", duration=0.06),
    Run("colliding_disks", "colliding_disks", head_start=1.2, duration=0.9),
    Run("cut2d", "cut2d", head_start=0.14, duration=0.075),
    Run("stork2d", "stork2d", duration=0.01),
)
RUN = {r.key: r for r in RUNS}
#: the runs of asynchronous examples: the candidate books one synchronous step beside the reference, which they have
#: not (their stages are the same and are compared on the synchronous runs)
ASYNCHRONOUS = ("stork2d",)


@dataclass(frozen=True)
class Params:
    runs: tuple = tuple(r.key for r in RUNS)
    coarsen: int = 1  # every example's cells divided by this (count-sampled bodies: their count by coarsen**dim)
    duration_factor: float = 3.0  # each run's simulated time is its duration times this
    whole_examples: bool = False  # each example from t = 0 (no head start) to its own end time
    compared: tuple | None = None  # runs whose ledger the candidate books beside the reference (None: every run)
    candidate: str = "numba"  # the candidate when the case is run on the reference
    frames: int = 8  # VTK frames per run
    friction_steps: int = 300  # steps of the sliding block (0.06 s)
    integration_t_end: float = 0.01  # simulated time of the integration-order study
    integration_levels: int = 3  # Δt, Δt/2, ... of that study

    @classmethod
    def quick(cls):
        """The examples on half their cells, each for its quick duration; the candidate on the runs whose kernels
        the other cases compile too (no CPIC); the integration study to 0.005 s."""
        return cls(coarsen=2, duration_factor=1.0, compared=("jelly-mls", "jelly-polypic", "snow88", "sand"),
                   frames=5, integration_t_end=0.005)

    @classmethod
    def full(cls):
        return cls(whole_examples=True, integration_levels=4)


# ------------------------------------------------------------------------------------------- scenes
def free_flight(data, t0):
    r"""The scene ``data`` (a TOML dict) with ``t0`` seconds of its bodies' free flight skipped.

    Each body is translated by :math:`v t_0 + \tfrac12 g t_0^2` and starts with velocity :math:`v + g t_0`: the
    exact free flight of an unstressed body, which every transfer reproduces (a uniform velocity field is kept by
    P2G and G2P alike, partition of unity). Only for bodies that meet nothing in that time.
    """
    g = np.asarray(data.get("gravity", [0.0] * data["dim"]), dtype=float)
    for body in data["bodies"]:
        v = np.asarray(body.get("velocity", [0.0] * data["dim"]), dtype=float)
        for key in ("lower", "upper", "center", "rotation_center"):
            if key in body:
                body[key] = (np.asarray(body[key]) + v * t0 + 0.5 * g * t0**2).tolist()
        body["velocity"] = (v + g * t0).tolist()
    return data


def coarsened(data, factor):
    """The scene ``data`` on a grid ``factor`` times coarser; a body sampled by count keeps its mass with
    ``factor**dim`` times fewer particles."""
    grid = data["grid"]
    if "cells" in grid:
        grid["cells"] = (np.asarray(grid["cells"]) // factor).tolist()
    else:
        grid["dx"] = grid["dx"] * factor
    for body in data["bodies"]:
        if "count" in body:
            body["count"] //= factor ** data["dim"]
            body["particle_volume"] *= factor ** data["dim"]
    return data


def example_end(data):
    """The example's own end time: ``time.t_end``, or ``time.steps`` times its fixed ``time.dt``."""
    t = data["time"]
    return t["t_end"] if "t_end" in t else t["steps"] * t["dt"]


def span(run, params, data):
    """``(head start, simulated time)`` of ``run`` (its example's TOML dict ``data``): its own, or the whole example
    from ``t = 0`` with ``params.whole_examples``."""
    if params.whole_examples:
        return 0.0, example_end(data)
    return run.head_start, run.duration * params.duration_factor


def example_data(run, params):
    """The TOML dict of ``run``'s scene (:func:`coarsened`, :func:`free_flight`, the ledger on) and its end time."""
    data = tomllib.loads((EXAMPLES / f"{run.example}.toml").read_text())
    if run.variant is not None:
        variant = VARIANT[run.variant]
        data["method"] = {"scheme": variant.scheme, **variant.method}
    head_start, t_end = span(run, params, data)
    data = free_flight(coarsened(data, params.coarsen), head_start)
    data.setdefault("output", {})["energy_ledger"] = True
    return data, t_end


def example_scene(run, params):
    """The scene of ``run``."""
    data, _ = example_data(run, params)
    return Scene.from_dict(data, base_dir=EXAMPLES)


#: what the claims let a backend that implements a part change in the examples and the friction block (the module
#: docstring of :mod:`verification.energy_ledger`)
ALLOWS = Allow(materials="substitute", walls="static", friction=True, kernel=True, dims=True)
FRICTION_ALLOWS = Allow(materials="substitute", kernel=True, force=True, dims=True)


def run_allows(run):
    """:data:`ALLOWS` for ``run``: the force free unless the run is a variant that names it
    (:meth:`~verification.momentum.Variant.allows`)."""
    return VARIANT[run.variant].allows(ALLOWS) if run.variant is not None else replace(ALLOWS, force=True)


def method_label(scene):
    """The scene's transfer scheme and force discretisation, for tables and figures."""
    m = scene.method
    flip = f"(α={m.flip_alpha:g})" if m.scheme == "flip" else ""
    return f"{m.scheme}{flip}, {m.force} force"


# ----------------------------------------------------------------------------------------- examples
def bodies_energy(sim):
    """The rigid bodies' kinetic and gravitational energy (0 without bodies)."""
    if sim.state.rigid is None:
        return 0.0
    return float(np.sum(rigid_dynamics.mechanical_energy(sim.scene.rigid_bodies, sim.state.rigid, sim.scene.gravity)))


def ledger_row(sim):
    """``[time, ledger columns...]``: the cumulative ledger (:data:`mpmref.observe.ledger.ASYNC_COLUMNS`: the
    synchronous columns and the ``interface`` term of asynchronous stepping, zero for a synchronous run) that the
    stepper keeps in the run's state, read as its diagnostics columns."""
    d = sim.stepper.diagnostics(sim.state)
    return [sim.time, *(d.get(f"ledger_{c}", 0.0) if c == "interface" else d[f"ledger_{c}"] for c in ASYNC_COLUMNS)]


def energies(sim):
    r"""``[step, K, Ψ, U, E_bodies]`` of the current state, from the diagnostics (kinetic: velocity, affine and
    mode parts)."""
    d = sim.diagnostics()
    return [sim.step_count, d["kinetic"] + d["kinetic_affine"] + d["kinetic_modes"], d["elastic"], d["gravitational"],
            bodies_energy(sim)]


def shared_terms(scene):
    """The per-particle terms that can be nonzero in ``scene``: ``plastic`` with a plastic material, ``advection``
    with PolyPIC modes."""
    return tuple(t for t, present in (("plastic", scene.tracks("Jp")), ("advection", scene.transfer.polypic))
                 if present)


def add_shares(totals, shares):
    """Add one step's per-particle shares (``EnergyLedger.shares``) to ``totals`` (``{term: array by particle id}``,
    grown as ids appear)."""
    ids = shares["id"]
    for term, total in totals.items():
        if ids.size and ids.max() >= total.size:
            totals[term] = total = np.concatenate([total, np.zeros(ids.max() + 1 - total.size)])
        total[ids] += shares[term]


def frame(sim, totals):
    """A VTK frame of the current particles with each one's cumulative share of the per-particle terms
    (``ledger_<term>``)."""
    time, x, data = snapshot(sim)
    return time, x, {**data, **{f"ledger_{term}": total[sim.id] for term, total in totals.items()}}


def compare_here(sim, candidate):
    """:func:`compare` from the current state of ``sim``, with the Δt the run would take next."""
    return compare(sim.scene, (sim.particles, sim.state.rigid, sim.time, sim.stepper.time_step(sim.particles)),
                   candidate)


def run_example(params, key, backend):
    """One run to its end (:func:`ledger_run`); for a compared run (:func:`compared_runs`), the candidate's ledger
    beside the reference's from the states half-way and at the end."""
    data, t_end = example_data(RUN[key], params)
    sim = Simulation(fit(Scene.from_dict(data, base_dir=EXAMPLES), backend, run_allows(RUN[key])).scene,
                     backend=backend)
    candidate = candidate_of(params, backend) if key in compared_runs(params) else None
    return ledger_run(sim, key, params.frames, t_end=t_end, candidate=candidate)


def ledger_run(sim, key, frames, t_end=None, steps=None, candidate=None):
    """Run ``sim`` (its scene books the ledger) to ``t_end``, or for ``steps`` steps of its own: per step its time and
    cumulative ledger (:func:`ledger_row`), at each of ``frames`` frames the diagnostics' energies (:func:`energies`)
    and a VTK frame with the per-particle shares; with a ``candidate`` backend, its ledger beside the reference's from
    the states half-way and at the end (``compared``, :func:`compare`; empty otherwise). ``left``: the particles the
    domain's edge deleted or clamped over the run (the ledger books steps, not those)."""
    first, left = sim.step_count, sim.deleted + sim.clamped
    totals = {term: np.zeros(sim.n_particles) for term in shared_terms(sim.scene)}
    compared, paused = [], []

    def halfway():  # half the run done, not all of it
        if steps is not None:
            return 2 * (sim.step_count - first) >= steps > sim.step_count - first
        return 0.5 * t_end * (1.0 - 1e-12) <= sim.time < t_end * (1.0 - 1e-12)

    def measure(sim):
        if totals and sim.step_count > first:
            add_shares(totals, sim.stepper.ledger.shares)
        if candidate and not compared and halfway():
            start = perf_counter()
            compared.append(compare_here(sim, candidate))
            paused.append(perf_counter() - start)  # the run's wall time leaves the candidate's step out
        return ledger_row(sim)

    run = record(sim, measure, frames, steps=steps, t_end=t_end, frame=lambda s: (energies(s), frame(s, totals)))
    if candidate:
        compared.append(compare_here(sim, candidate))
    h, e = np.array(run.rows), np.array([sample for sample, _ in run.frames])
    return {"key": key, "method": method_label(sim.scene), "n_particles": sim.n_particles,
            "steps": sim.step_count - first, "wall_s": run.wall_s - sum(paused), "t": h[:, 0], "ledger": h[:, 1:],
            "sampled_steps": e[:, 0].astype(int) - first, "energies": e[:, 1:], "frames": [f for _, f in run.frames],
            "compared": compared, "left": sim.deleted + sim.clamped - left,
            **signs_fixed(sim.scene)}


def signs_fixed(scene):
    """Which of the ledger's signs theory fixes for ``scene`` (docs/energy_ledger.md), as flags: ``projection``, the
    transfers are averages and projections (PIC, APIC, MLS-MPM, PolyPIC without rigid bodies: P2G and G2P never
    raise the kinetic energy); ``full_modes``, PolyPIC's G2P represents the grid's velocity exactly; ``static``, walls
    or colliders act and none moves (``boundary`` never positive); ``plastic``, a plastic material's return map acts
    (``plastic`` never positive)."""
    walls = any(w.type != "open" for w in scene.boundary.walls.values()) or bool(scene.colliders)
    return {"projection": not scene.transfer.flip and not scene.rigid_bodies,
            "full_modes": scene.transfer.polypic and not scene.rigid_bodies,
            "static": walls and all(np.all(c.velocity == 0.0) for c in scene.colliders),
            "plastic": scene.tracks("Jp")}


def total_energy(r):
    """The run's total energy :math:`K + \\Psi + U + E_{bodies}` at each sampled step (``r["sampled_steps"]``)."""
    return r["energies"].sum(axis=1)


def run_scale(r):
    """The run's energy scale: the largest :func:`mpmref.observe.ledger.energy_scale` over its sampled states."""
    return max(energy_scale(*row) for row in r["energies"])


def terms_of(r):
    """``{term: (n+1,) cumulative joules}`` of a run (zero at the start)."""
    return {term: r["ledger"][:, ASYNC_COLUMNS.index(term)] for term in ASYNC_TERMS}


# ----------------------------------------------------------------------------------------- friction
#: the sliding block: friction coefficient, gravity, initial speed, cells across the unit domain, Δt
FRICTION = {"mu": 0.3, "g": 10.0, "speed": 1.0, "cells": 32, "dt": 2e-4}


def friction_scene(mu, g, cells, dt):
    """An elastic block (0.2 × 0.1) resting on a ``separate`` floor with Coulomb friction ``mu``, APIC."""
    dx = 1.0 / cells
    return (SceneBuilder(dim=2, name="friction_block").grid(size=1.0, cells=cells).method("apic")
            .material("m", "fixed_corotated", E=1e3, nu=0.3, rho=1.0)
            .box("m", lower=[0.2, 3 * dx], upper=[0.4, 3 * dx + 0.1], ppc=4)
            .walls("separate", friction=mu).gravity([0.0, -g]).time(dt=dt).output(energy_ledger=True).build())


def run_friction(params, backend):
    r"""The block given ``speed`` along the floor, ``friction_steps`` steps: per step the time, the distance its
    centre of mass slid and the cumulative ``boundary`` term; its mass, :math:`\mu` and :math:`g`."""
    f = FRICTION
    sim = Simulation(fit(friction_scene(f["mu"], f["g"], f["cells"], f["dt"]), backend, FRICTION_ALLOWS).scene,
                     backend=backend)
    sim.v = np.broadcast_to([f["speed"], 0.0], sim.v.shape).copy()
    mass = float(sim.mass.sum())
    x0 = float(sim.mass @ sim.x[:, 0]) / mass
    rows = [(0.0, 0.0, 0.0)]
    for _ in range(params.friction_steps):
        sim.step()
        rows.append((sim.time, float(sim.mass @ sim.x[:, 0]) / mass - x0, sim.diagnostics()["ledger_boundary"]))
    h = np.array(rows)
    return {"t": h[:, 0], "distance": h[:, 1], "boundary": h[:, 2], "mass": mass, "mu": f["mu"], "g": f["g"]}


# -------------------------------------------------------------------------------------- integration
#: the integration study's problem: the energy case's oscillating jelly (quick preset) under MLS-MPM
INTEGRATION = {"problem": "jelly", "variant": "mls"}


def run_integration(params, backend):
    r"""The summed size :math:`\sum_n |\texttt{integration}_n|` over the steps to ``integration_t_end`` at
    :math:`\Delta t, \Delta t/2, \ldots` (``integration_levels``), :math:`\Delta t` the first step's CFL step
    rounded to divide the time: ``{"dt": [...], "size": [...]}``."""
    t_end, dts, sizes = params.integration_t_end, [], []
    for level in range(params.integration_levels):
        sim = energy.make_simulation(energy.Params.quick(), INTEGRATION["problem"], VARIANT[INTEGRATION["variant"]],
                                     backend, ledger=True)
        n = math.ceil(t_end / sim.stepper.time_step(sim.particles)) * 2**level
        size = 0.0
        for _ in range(n):
            sim.step(t_end / n)
            size += abs(sim.stepper.ledger.last["integration"])
        dts.append(t_end / n)
        sizes.append(size)
    return {"dt": np.array(dts), "size": np.array(sizes)}


# ------------------------------------------------------------------------------------ the candidate
def compare(scene, state, candidate):
    """One step from ``state``, ``(particles, rigid, time, dt)``, booked on the NumPy reference and on ``candidate``:
    the largest error of the candidate's ledger terms, each :math:`|a - r| / S` with the reference's energy scale
    :math:`S` (the conformance harness's rule, :func:`mpmref.conformance.report.output_scale`), and which."""
    particles, rigid, time, dt = state
    books = {name: ledger_step(make_backend(name, scene), particles.copy(), dt, time, rigid)
             for name in ("numpy", candidate)}
    errors, _ = compare_outputs(books[candidate], books["numpy"])
    worst = max(errors, key=errors.get)
    return {"error": errors[worst], "worst": worst, "reference": books["numpy"], "candidate": books[candidate]}


# ---------------------------------------------------------------------------------------------- all
def parts(params, backend, triage=None):
    """``{name: (function, args)}``: the case's independent runs, each ``function(params, *args, backend)``; with a
    :class:`~verification.framework.applicable.Triage`, only those that ``backend`` implements (it lists the others)."""
    f = FRICTION
    scenes = {**{f"run/{key}": (f"{key} (the run and its checks)", example_scene(RUN[key], params),
                                run_allows(RUN[key])) for key in params.runs},
              "friction": ("friction block: boundary / (mu m g d)", friction_scene(f["mu"], f["g"], f["cells"],
                                                                                   f["dt"]), FRICTION_ALLOWS),
              "integration": ("integration: fitted slope of sum |integration| against dt",
                              energy.problem_scene(energy.Params.quick(), INTEGRATION["problem"],
                                                   VARIANT[INTEGRATION["variant"]]),
                              VARIANT[INTEGRATION["variant"]].allows(energy.ALLOWS))}
    functions = {**{f"run/{key}": (run_example, (key,)) for key in params.runs},
                 "friction": (run_friction, ()), "integration": (run_integration, ())}
    if triage is None:
        return functions
    return {job: functions[job] for job, (name, scene, allow) in scenes.items()
            if triage.scene(name, scene, allow, run=job.removeprefix("run/")) is not None}


def run_part(job):
    """``function(params, *args, backend)`` of one entry of :func:`parts` (module level: picklable)."""
    function, params, args, backend = job
    return function(params, *args, backend)


def compared_runs(params):
    """The runs whose ledger the candidate books too."""
    runs = params.runs if params.compared is None else tuple(k for k in params.compared if k in params.runs)
    return tuple(k for k in runs if k not in ASYNCHRONOUS)


def candidate_of(params, backend):
    """The backend compared with the reference: ``params.candidate`` when the case runs on the reference, else the
    backend it runs on."""
    return params.candidate if backend == "numpy" else backend
