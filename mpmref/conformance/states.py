r"""The seeded random states of the conformance cases: particles, grid states, Δt and time, drawn at given scales.

A case's state is drawn from a generator seeded by its name, so it is the same on every machine. Its magnitudes
are a :class:`Scales`: those of the built-in catalogue (:func:`catalogue_scales`, set by the case's cell size), or
those of a user's scene (:func:`mpmref.conformance.scenes.scene_scales`: its cell size, its bodies' speeds, its
materials' wave speeds, its gravity). Δt is drawn from a CFL number over nearly four decades inside the stable range
(:func:`draw_step`), the time over three decades (:func:`draw_time`).
"""

import zlib
from dataclasses import dataclass

import numpy as np

from ..physics.kernels import compute_stencil
from ..physics.materials import evolved_fields
from ..physics.polypic import higher_modes

#: the cell size at which the built-in cases' velocities are of order 1; they scale with the cell size, so that a
#: state moves the same number of cells per second on every grid
REFERENCE_DX = 1.0 / 8
#: particles stay at least this many cells away from every face of the domain
EDGE_CELLS = 2
N_PARTICLES = {2: 64, 3: 128}
#: smallest per-axis kernel weight a particle may have (see :func:`random_positions`). 1e-4 was enough on the unit
#: box of 8 cells; with the drawn grids and steps, two 3D PolyPIC steps (classic force) moved their modes by
#: 1.0e-13 and 1.3e-13 for a 1e-15 input change (a top mode's norm is a product of per-axis factors, one per
#: axis); at 1e-3 the largest over every case is 4.1e-14
MIN_WEIGHT = 1.0e-3
#: the CFL number of a case, Δt (c + 4 s) / Δx, is drawn log-uniformly in this range (:func:`draw_step`)
CFL_RANGE = (1.0e-4, 0.5)
#: the plastic volume ratios ``Jp`` of a drawn state are uniform in this range
JP_RANGE = (0.7, 1.2)
#: the time of a case (where colliders and scripted bodies are) is drawn log-uniformly in this range, times the
#: time scale of its :class:`Scales`
TIME_RANGE = (1.0e-4, 0.2)


@dataclass(frozen=True)
class Scales:
    r"""The magnitudes a case's random state is drawn at.

    Attributes
    ----------
    speed : float             :math:`s`: particle velocities are N(0, s²); grid velocities too
    affine : float            the entries of the affine matrix :math:`C_p` are N(0, affine²) (a velocity gradient)
    force_per_speed : float   node forces per unit mass are N(0, (force_per_speed · s)²)
    density : float           node masses are in [0.2, 1.5] density Δx^d
    time : float              the time of a case is :data:`TIME_RANGE` times this
    """

    speed: float
    affine: float
    force_per_speed: float
    density: float = 1.0
    time: float = 1.0


def catalogue_scales(scene):
    """The scales of a built-in case: speed Δx / (1/8) (order 1 at Δx = 1/8: a state moves as many cells per unit
    time on every grid), ``C`` N(0, 4²), node forces per unit mass 50 s, node masses in Δx^d units, time 1."""
    return Scales(speed=scene.grid.dx / REFERENCE_DX, affine=4.0, force_per_speed=50.0)


# ------------------------------------------------------------------------------------------- particles
def random_rotations(rng, n, dim):
    """``n`` uniformly random proper rotations (QR of Gaussian matrices with the sign fixed)."""
    q, r = np.linalg.qr(rng.standard_normal((n, dim, dim)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    q[np.linalg.det(q) < 0, :, 0] *= -1.0
    return q


def random_deformation_gradients(rng, n, dim, min_det=0.3):
    """``F = R (I + s G)``: random rotation ``R``, Gaussian ``G``, ``s`` log-uniform in [1e-3, 0.2]; det F > min_det.

    Small ``s`` leave snow and sand inside their yield surface, large ones outside, so both branches of each
    return map are exercised.
    """
    F = np.empty((n, dim, dim))
    todo = np.arange(n)
    while todo.size:
        s = np.exp(rng.uniform(np.log(1e-3), np.log(0.2), todo.size))
        stretch = np.eye(dim) + s[:, None, None] * rng.standard_normal((todo.size, dim, dim))
        F[todo] = random_rotations(rng, todo.size, dim) @ stretch
        todo = todo[np.linalg.det(F[todo]) <= min_det]
    return F


def random_modes(rng, n, dim, support, dx, speed=1.0):
    """PolyPIC coefficients scaled by ``dx^-degree``, so that each mode adds O(0.1) ``speed`` to a node's velocity."""
    degree = higher_modes(dim, support).sum(axis=1)
    return 0.1 * speed * rng.standard_normal((n, len(degree), dim)) / (dx ** degree)[None, :, None]


def random_positions(scene, rng, n):
    """``n`` positions at least ``EDGE_CELLS`` cells inside the domain whose per-axis kernel weights are all
    at least ``MIN_WEIGHT``.

    Where a particle's outermost weight vanishes (at cell centres for the quadratic B-spline, on nodes for
    the cubic), PolyPIC's top mode norms vanish too and G2P divides by them: there a 1e-15 relative change of
    the inputs moved the output modes by up to 2.5e-7 relative, so no threshold near round-off could be
    asked of a correct implementation. With the margin the same perturbation moves every output by < 1e-13
    (4.1e-14 at most, measured on every case).
    """
    grid = scene.grid
    lo = grid.origin + EDGE_CELLS * grid.dx
    hi = grid.origin + (np.array(grid.cells) - EDGE_CELLS) * grid.dx  # each axis its own count
    x = np.empty((0, scene.dim))
    while len(x) < n:
        trial = lo + (hi - lo) * rng.random((n, scene.dim))
        weights = compute_stencil(scene.kernel, trial, grid.origin, grid.dx).w
        x = np.concatenate([x, trial[weights.min(axis=(1, 2)) >= MIN_WEIGHT]])
    return x[:n]


def random_particles(scene, rng, scales=None):
    """A particle state for ``scene`` as a flat dict, at ``scales`` (default :func:`catalogue_scales`).

    Positions from :func:`random_positions`; random materials of the scene; volume a quarter cell (2D) or
    an eighth (3D) within ±20 %; mass ``rho * vol0``; velocities N(0, s²); ``C`` N(0, affine²); ``F`` from
    :func:`random_deformation_gradients`; ``J`` in [0.9, 1.1]; ``Jp`` in :data:`JP_RANGE`; PolyPIC modes from
    :func:`random_modes`. ``C``, ``F``, ``J``, ``Jp`` and ``modes`` only where the scene needs them.
    """
    scales = scales or catalogue_scales(scene)
    grid, dim, speed = scene.grid, scene.dim, scales.speed
    n = N_PARTICLES[dim]
    material = rng.integers(len(scene.materials), size=n).astype(np.int32)
    vol0 = grid.dx**dim / 2**dim * rng.uniform(0.8, 1.2, n)
    rho = np.array([m.rho for m in scene.material_list])[material]
    flat = {"x": random_positions(scene, rng, n), "v": speed * rng.standard_normal((n, dim)), "mass": rho * vol0,
            "vol0": vol0, "material": material}
    if scene.transfer.affine:
        flat["C"] = scales.affine * rng.standard_normal((n, dim, dim))
    if scene.tracks("F"):
        flat["F"] = random_deformation_gradients(rng, n, dim)
    if scene.tracks("J"):
        flat["J"] = rng.uniform(0.9, 1.1, n)
    if scene.tracks("Jp"):
        flat["Jp"] = rng.uniform(*JP_RANGE, n)
    if scene.transfer.polypic:
        flat["modes"] = random_modes(rng, n, dim, scene.kernel.support, grid.dx, speed)
    return flat


def random_grid(scene, rng, scales=None):
    """Grid state after a P2G: a quarter of the nodes empty, the others with mass in [0.2, 1.5] density Δx^d,
    velocity N(0, s²) and force per unit mass N(0, (force_per_speed s)²) (``scales``, default
    :func:`catalogue_scales`)."""
    scales = scales or catalogue_scales(scene)
    n_nodes, dim, speed = scene.grid.n_nodes, scene.dim, scales.speed
    mass = scales.density * scene.grid.dx**dim * rng.uniform(0.2, 1.5, n_nodes) * (rng.random(n_nodes) >= 0.25)
    return {"grid_mass": mass, "grid_momentum": mass[:, None] * speed * rng.standard_normal((n_nodes, dim)),
            "grid_force": mass[:, None] * scales.force_per_speed * speed * rng.standard_normal((n_nodes, dim))}


# ----------------------------------------------------------------------------------------- Δt and time
def draw_step(label, scene, speed=None, limit=None):
    r"""Δt of the case called ``label``: :math:`\Delta t = \mathrm{CFL}\,\Delta x / (c + 4 s)` with the CFL number
    log-uniform in :data:`CFL_RANGE` (nearly four decades, all inside the stable range of every scheme,
    docs/stability.md), :math:`c` the largest wave speed of a drawn state (:func:`drawn_wave_speed`) and :math:`s`
    the state's speed scale
    (``speed``, default :func:`catalogue_scales`' ; four standard deviations bound the drawn speeds). Seeded by the
    label.

    ``limit`` is a bound on Δt that the scene has besides the CFL rule (CPIC's penalty, :math:`k \Delta t \le 1`):
    where the CFL range reaches past it, every Δt is scaled down by one factor, so that the range keeps its four
    decades and its top is the limit.
    """
    speed = catalogue_scales(scene).speed if speed is None else speed
    cfl = np.exp(np.random.default_rng(zlib.crc32(f"dt-{label}".encode())).uniform(*np.log(CFL_RANGE)))
    signal = drawn_wave_speed(scene) + 4.0 * speed
    dt = step_at(scene, cfl, speed)
    if limit is not None:
        dt *= min(1.0, limit / (CFL_RANGE[1] * scene.grid.dx / signal))
    return dt


def step_at(scene, cfl, speed):
    r"""Δt at the CFL number ``cfl``: :math:`\mathrm{CFL}\,\Delta x / (c + 4 s)` (the rule of :func:`draw_step`, at one
    CFL number; :math:`c` of :func:`drawn_wave_speed`, :math:`s` = ``speed``)."""
    return float(cfl * scene.grid.dx / (drawn_wave_speed(scene) + 4.0 * speed))


def cfl_number(scene, dt=None, speed=None):
    """The CFL number of a case's scene as :func:`draw_step` drew it: ``dt (c + 4 s) / dx`` (``dt`` default the
    scene's ``time.dt``, ``speed`` default :func:`catalogue_scales`')."""
    dt = scene.time.dt if dt is None else dt
    speed = catalogue_scales(scene).speed if speed is None else speed
    return dt * (drawn_wave_speed(scene) + 4.0 * speed) / scene.grid.dx


def drawn_wave_speed(scene):
    r"""The largest wave speed of a particle of ``scene`` at rest (:func:`rest_wave_speeds`)."""
    return float(np.max(rest_wave_speeds(scene)))


def rest_wave_speeds(scene):
    r"""The wave speed of each material of ``scene`` (in the order of its ``material_list``) for a particle at rest
    (:math:`F = I`, :math:`J = 1`) with the plastic volume ratio a drawn state goes down to (``JP_RANGE[0]``): each
    material's own rule (``wave_speeds``), so that snow is as stiff as its hardening makes the drawn states, and not as
    stiff as its clamp ``Jp_min`` would allow (a code that never clamps declares ``Jp_min = 1e-300``)."""
    state = {"F": np.eye(scene.dim)[None], "J": np.ones(1), "Jp": np.full(1, JP_RANGE[0])}
    return np.array([float(m.wave_speeds(*(state[f] for f in evolved_fields(m)))[0]) for m in scene.material_list])


def draw_time(seed, scale=1.0):
    """The time of a case (log-uniform in :data:`TIME_RANGE`, times ``scale``): where the moving colliders and the
    scripted bodies are."""
    return scale * float(np.exp(np.random.default_rng([seed, 1]).uniform(*np.log(TIME_RANGE))))


# ------------------------------------------------------------------------------- asynchronous stepping
def random_classes(rng, n):
    """The particle classes of a level update (:mod:`mpmref.physics.interface`): active, finer ghost or coarser
    shadow, each with probability 1/3 (int64)."""
    return rng.integers(3, size=n).astype(np.int64)


def random_subset(rng, n):
    """About half of ``n`` particle indices, sorted (int64): the ``idx`` of a ``wave_speeds`` case."""
    return np.flatnonzero(rng.random(n) < 0.5).astype(np.int64)
