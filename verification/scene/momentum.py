r"""Momentum of the user's scene: its bodies drifting and spinning rigidly, with nothing external acting.

The scene's bodies and materials, on its grid, scheme and kernel, with gravity, walls (open), colliders, rigid bodies
and emitters removed, on a domain padded so that nothing leaves it over the run (:func:`momentum_scene`). Every body
starts from one rigid motion, :math:`v = v_c + \omega \times (x - x_c)` with the centre of mass :math:`x_c` and the
velocity of the centre of mass :math:`v_c` of the scene's own initial state, :math:`C_p = \nabla v` for the affine
schemes (:func:`mpmref.scene.sampling.initial_velocity`); :math:`|\omega| R` is :data:`SPIN_MACH` of the fastest wave
speed (:math:`R` the farthest particle from :math:`x_c`; about the z axis in 3D). No external force acts, so:

* **linear momentum** :math:`P` is conserved by every transfer, and **angular momentum** :math:`L` about
  :math:`x_c` (the affine part included; conserved about any fixed point, and :math:`x_c`'s own drift adds nothing,
  being along :math:`v_c`) by APIC, MLS-MPM and PolyPIC: both drifts are held to the round-off bound
  :func:`verification.momentum.roundoff_bound` of the run (its steps, particles, the most particles in a cell of the
  initial state, the kernel's support, the dimension, the machine epsilon of the scene's dtype), relative to
  :math:`S_P = \sum_p m_p |v_p|` and :math:`S_L = \sum_p m_p (|x_p - x_c| |v_p| + D |C_p|)`;
* **PIC and FLIP(α < 1)** drop the affine spin of each particle in G2P: the spin's share of :math:`L` decays by
  :math:`(1-\alpha)\,2DM/I` per step (:func:`verification.momentum.spin_loss_rate`; :math:`I` about the spin axis),
  and the measured decay rate must be at least half of that; FLIP(1)'s angular momentum changes by more than
  round-off.

On a backend without open walls, the walls are its own on a domain padded by their band, which nothing reaches
(:mod:`verification.framework.applicable`).
"""

import math

import numpy as np

from mpmref import Simulation
from mpmref.observe.diagnostics import angular_momentum
from mpmref.scene.parsers import CPIC_KEYS
from mpmref.scene.sampling import sample_particles

from ..framework.applicable import Allow, Triage
from ..framework.case import VerificationCase
from ..framework.common import Check
from ..momentum import decay_rate, roundoff_bound
from . import Params, as_run, figure_with, load, what_ran, write_report

#: the spin's edge speed, in units of the scene's fastest wave speed (the momentum case spins its disk at about 0.01)
SPIN_MACH = 0.01
#: what a backend that implements a part may change: its own walls for the open ones, which nothing reaches
ALLOWS = Allow(walls="open")


# ------------------------------------------------------------------------------------------------------- scene
def rigid_motion(scene):
    """The scene's centre of mass :math:`x_c`, its velocity :math:`v_c`, the farthest particle's distance :math:`R`
    from it and the spin :math:`\\omega` (a scalar in 2D, a vector along z in 3D) of the rigid start."""
    particles = sample_particles(scene)
    m, x = particles.mass.astype(float), particles.x.astype(float)
    center, velocity = m @ x / m.sum(), m @ particles.v.astype(float) / m.sum()
    radius = float(np.max(np.linalg.norm(x - center, axis=1)))
    omega = SPIN_MACH * scene.max_wave_speed() / max(radius, scene.grid.dx)
    return center, velocity, radius, omega if scene.dim == 2 else [0.0, 0.0, omega]


def momentum_scene(scene, steps):
    """The scene of the check (module docstring): its bodies moving rigidly, nothing external, the domain padded by
    the distance a particle may travel over ``steps`` steps (speed :math:`|v_c| + |\\omega| R` plus the centrifugal
    drift :math:`|\\omega|^2 R\\,T^2`) and the kernel's support on every side, so no particle leaves it."""
    center, velocity, radius, omega = rigid_motion(scene)
    spin = float(np.linalg.norm(omega))
    bodies = []
    for body in copy_bodies(scene):
        body.pop("velocity_gradient", None)
        bodies.append({**body, "velocity": velocity.tolist(), "angular_velocity": omega,
                       "rotation_center": center.tolist()})
    dx, speed = scene.grid.dx, float(np.linalg.norm(velocity)) + spin * radius
    dt = scene.time.dt or scene.time.cfl * dx / (scene.max_wave_speed() + speed)
    travel = speed * steps * dt + spin**2 * radius * (steps * dt) ** 2
    pad = math.ceil(2.0 * travel / dx) + scene.kernel.support + 1
    grid = {"origin": (scene.grid.origin - pad * dx).tolist(),
            "size": ((np.array(scene.grid.cells) + 2 * pad) * dx).tolist(), "dx": dx, "block": scene.grid.block}
    method = {k: v for k, v in scene.source.get("method", {}).items() if k not in ("coupling", *CPIC_KEYS)}
    return as_run(scene, name=f"{scene.name}_momentum", grid=grid, bodies=bodies, gravity=[0.0] * scene.dim,
                  colliders=[], rigid_bodies=[], emitters=[], method=method,
                  boundary={"type": "open", "width": scene.boundary.width, "domain_exit": "error"})


def copy_bodies(scene):
    return [dict(b) for b in scene.source["bodies"]]


def most_per_cell(scene):
    """The most particles in one cell of the scene's initial state (the ``ppc`` of the round-off bound)."""
    x = sample_particles(scene).x
    cells = np.floor((x - scene.grid.origin) / scene.grid.dx).astype(np.int64)
    return int(np.unique(cells, axis=0, return_counts=True)[1].max())


# --------------------------------------------------------------------------------------------------------- run
def run(params, backend="numpy", executor=None):
    """Run the check's scene on ``backend`` for the budget's steps: P, L about the centre of mass and their scales
    every step (``executor`` is not used: one run)."""
    scene = load(params)
    steps = params.steps(sample_particles(scene).n)
    triage = Triage(backend)
    fitted = triage.scene(f"{scene.name}: momentum (every check)", momentum_scene(scene, steps), ALLOWS,
                          run=f"{scene.name}_momentum")
    if fitted is None:
        raise triage.nothing_ran()
    sim = Simulation(fitted, backend=backend)
    center, _, _, _ = rigid_motion(fitted)
    inertia = fitted.kernel.inertia_factor * fitted.grid.dx**2
    rate = spin_loss_rate(sim, center, inertia)
    rows = [measure(sim, center, inertia)]
    for _ in range(steps):
        sim.step()
        rows.append(measure(sim, center, inertia))
    t, P, L, scale_P, scale_L = (np.array(column) for column in zip(*rows))
    return {"params": params, "backend": backend, "scene": scene.name, "t": t, "P": P, "L": L,
            "scale_P": float(scale_P.max()), "scale_L": float(scale_L.max()), "steps": steps,
            "n_particles": sim.n_particles, "ppc": most_per_cell(fitted), "support": fitted.kernel.support,
            "dim": fitted.dim, "eps": float(np.finfo(fitted.dtype).eps), "transfer": fitted.transfer,
            "spin_loss_rate": rate, "ran": what_ran(scene, steps, step_text(fitted)), **triage.record()}


def step_text(scene):
    """How the scene's steps are sized, for the report."""
    return f"Δt = {scene.time.dt:g}" if scene.time.dt is not None else f"Δt by the CFL rule at {scene.time.cfl:g}"


def measure(sim, center, inertia):
    """Time, P, L about ``center`` (the affine part included; the z component in 3D, the spin's axis) and the scales
    :math:`S_P`, :math:`S_L`."""
    p = sim.particles
    m, v = p.mass.astype(float), p.v.astype(float)
    r = p.x.astype(float) - center
    speed = np.linalg.norm(v, axis=1)
    affine = 0.0 if p.C is None else inertia * float(np.sum(m * np.abs(p.C.astype(float)).sum(axis=(1, 2))))
    L = angular_momentum(p.with_(x=r), inertia)
    return sim.time, m @ v, np.atleast_1d(L), float(m @ speed), float(m @ (np.linalg.norm(r, axis=1) * speed)) + affine


def spin_loss_rate(sim, center, inertia):
    r""":math:`\lambda = 2 D M / I` of the initial state (:func:`verification.momentum.spin_loss_rate`), with :math:`I`
    the moment of inertia about the spin's axis through ``center`` (z in 3D)."""
    r = (sim.x.astype(float) - center)[:, :2]  # the components across the axis
    m = sim.mass.astype(float)
    return 2.0 * inertia * float(m.sum()) / float(np.sum(m * np.sum(r * r, axis=1)))


# ------------------------------------------------------------------------------------------------------ checks
def drifts(r):
    """Relative drift of P and of L against time: :math:`|P - P_0|/S_P`, :math:`|L - L_0|/S_L`."""
    return (np.linalg.norm(r["P"] - r["P"][0], axis=1) / r["scale_P"],
            np.linalg.norm(r["L"] - r["L"][0], axis=1) / r["scale_L"])


def bound(r, steps=None):
    """:func:`verification.momentum.roundoff_bound` of the run (after ``steps`` steps; default all)."""
    return roundoff_bound(r["steps"] if steps is None else steps, r["n_particles"], r["ppc"], r["support"], r["dim"],
                          r["eps"])


def checks(result):
    """P to round-off for every scheme; L to round-off for the affine schemes, its loss for PIC and FLIP (module
    docstring)."""
    r, spec = result, result["transfer"]
    dp, dl = drifts(r)
    limit = float(bound(r))
    name = f"{r['scene']} ({spec.scheme}{'(α=%g)' % spec.flip_alpha if spec.flip else ''})"
    out = [Check(f"{name}: linear momentum drift ‖P-P0‖ / Σ m‖v‖", float(dp.max()), "<=", limit,
                 "conserved exactly by every transfer; round-off (k n + N) u")]
    if spec.affine:
        out.append(Check(f"{name}: angular momentum drift ‖L-L0‖ / Σ m(‖x-xc‖‖v‖ + D‖C‖)", float(dl.max()), "<=",
                         limit, "conserved exactly with the affine term; round-off (k n + N) u"))
    elif not spec.flip or spec.flip_alpha < 1.0:
        predicted = (1.0 - (spec.flip_alpha if spec.flip else 0.0)) * r["spin_loss_rate"]
        axis = r["L"][:, -1]
        out.append(Check(f"{name}: angular momentum loss per step", decay_rate(axis / axis[0]), ">=",
                         0.5 * predicted, f"half the predicted (1-α)·2DM/I = {predicted:.3g} per step"))
    else:
        out.append(Check(f"{name}: angular momentum change ‖L-L0‖ / Σ m(‖x-xc‖‖v‖ + D‖C‖)", float(dl.max()), ">",
                         limit, "no affine mode carries the spin: not conserved (exceeds round-off)"))
    return out


# ------------------------------------------------------------------------------------------------------ report
def plot(result, path):
    """The drifts of P and L against time, with the round-off bound."""
    floor = result["eps"] / 8  # exact zeros are drawn at this floor

    def draw(ax):
        for drift, label in zip(drifts(result), ("‖P-P0‖ / S_P", "‖L-L0‖ / S_L")):
            ax.semilogy(result["t"], np.maximum(drift, floor), label=label)
        ax.semilogy(result["t"], bound(result, np.arange(len(result["t"]))), "k--", label="round-off bound (k n + N) u")

    return figure_with(draw, path, (
        f"{result['scene']} drifting and spinning rigidly, with no gravity, wall or collider acting: the drift of "
        "linear and angular momentum against time, with the round-off bound (dashed). Look for linear momentum under "
        "the bound for every scheme, angular momentum under it for APIC, MLS-MPM and PolyPIC (PIC and FLIP lose the "
        "spin: checked against its predicted rate instead)."),
        xlabel="time [s]", ylabel="relative drift", title=f"{result['scene']}: momentum, nothing external")


def report(result, out_dir):
    """Write the drift plot and ``momentum.md``."""
    return write_report(out_dir, "momentum", f"Momentum of {result['scene']}", result, checks(result), plot)


#: this check, for ``mpmref verify --scene``
CASE = VerificationCase(__doc__, Params, run, checks, report)
