"""The scenes of the CPIC case (:mod:`verification.cpic`): its parameters and one builder per scene.

Every 2D scene but the sand wheel is a unit square of ``params.cells`` cells with separate walls, a scene's
step fixed at CFL 0.3 (:func:`fixed_dt`); the 3D cut has its own grid (``params.cut3d_cells``), the sand wheel
its own (``params.wheel_cells``).
"""

from dataclasses import dataclass

import numpy as np

from mpmref import Scene, SceneBuilder
from mpmref.rigid.polyline import SAND_WHEEL
from mpmref.rigid.trimesh import validate_trimesh
from mpmref.scene.factories import add_sand_wheel
from mpmref.scene.sampling import sample_particles


@dataclass(frozen=True)
class Params:
    """The case's parameters: grid sizes, durations and speeds of its scenes, and what runs (the defaults are the
    standard preset)."""

    cells: int = 64          # across the unit domain
    drop_t_end: float = 2.0  # jelly falling onto a segment for 2 s
    impact_speed: float = 5.0
    rotor_omega: float = 10.0  # rad/s
    rotor_t_end: float = 0.3
    impact_t_end: float = 0.3
    sand_t_end: float = 0.3  # blade through sand
    blade_speed: float = 1.0
    ball_t_end: float = 0.2  # plate hit by a ball
    cut_t_end: float = 1.0   # jelly onto a wedge blade
    friction_t_end: float = 0.5
    mu: float = 0.3
    g: float = 10.0
    frames: int = 8
    cut3d_cells: int = 24     # the 3D cut: cells across the unit cube
    cut3d_t_end: float = 0.3
    extended: bool = True  # the rotor and the baselines (default and full presets)
    backend: str = "numpy"  # every simulation of the case runs on it (``run`` sets it from its argument)
    wheel_cells: int = 64    # the sand wheel (the reference scene has 400)
    wheel_t_end: float = 1.5  # the acceptance asks for 3 s (the full preset)
    wheel_fit: str = "per_body"  # method.cpic_fit of the sand wheel (docs/cpic.md, "Per-body fit")

    @classmethod
    def quick(cls):
        """The small preset the tests run (no rotor, no baselines)."""
        return cls(cells=32, drop_t_end=0.5, sand_t_end=0.15, ball_t_end=0.1, cut_t_end=0.45, friction_t_end=0.45,
                   extended=False, cut3d_cells=16, cut3d_t_end=0.1, wheel_cells=48, wheel_t_end=0.4)

    @classmethod
    def full(cls):
        """The largest preset (the sand wheel for the acceptance's 3 s)."""
        return cls(cells=128, cut3d_cells=40, cut3d_t_end=0.4, wheel_cells=128, wheel_t_end=3.0)


def _base(params, name, scheme="mls", gravity=True, walls="separate", **method):
    """A builder for a 2D CPIC scene on the unit square: ``params.cells`` cells, gravity ``params.g``."""
    method = {"coupling": "cpic", **method}
    b = (SceneBuilder(dim=2, name=name).grid(size=1.0, cells=params.cells).method(scheme, **method)
         .walls(walls, domain_exit="delete"))
    return b.gravity([0.0, -params.g if gravity else 0.0])


def drop_scene(params):
    """A jelly block falling 0.15 onto a fixed horizontal segment (wider than the block) at y = 0.3."""
    b = _base(params, "cpic_drop", penalty=1e3).material("jelly", "fixed_corotated", E=2e4, nu=0.3, rho=100.0)
    b.box("jelly", lower=[0.4, 0.45], upper=[0.6, 0.55])
    b.rigid_body([[0.2, 0.3], [0.8, 0.3]], [[0, 1]], motion="fixed")
    return b.time(dt=fixed_dt(params, 2e4, 100.0), t_end=params.drop_t_end).build()


def impact_scene(params):
    """The jelly block of :func:`drop_scene` starting just above the segment at ``impact_speed`` downwards."""
    b = _base(params, "cpic_impact", penalty=1e3).material("jelly", "fixed_corotated", E=2e4, nu=0.3, rho=100.0)
    b.box("jelly", lower=[0.4, 0.34], upper=[0.6, 0.44], velocity=[0.0, -params.impact_speed])
    b.rigid_body([[0.2, 0.3], [0.8, 0.3]], [[0, 1]], motion="fixed")
    return b.time(dt=fixed_dt(params, 2e4, 100.0), t_end=params.impact_t_end).build()


def sand_scene(params, pushing_force=None):
    r"""A vertical blade moving at ``blade_speed`` through a sand layer resting on the floor.

    The pushing force (default) is set so that a near particle's ghost velocities get
    :math:`f_{push}\Delta t\Delta x = 1.5\times` the blade's speed: the ghost term scales as
    :math:`\Delta t\Delta x`, so a fixed :math:`f_{push}` pushes less on a finer grid (the reference's
    2e4 gives 0.78 m/s at 32 cells, 0.2 m/s at 64). ``pushing_force`` overrides it.
    """
    dt = fixed_dt(params, 3e4, 1000.0)
    push = 1.5 * params.blade_speed / (dt / params.cells) if pushing_force is None else pushing_force
    b = _base(params, "cpic_sand", penalty=1e3, pushing_force=push)
    b.material("sand", "sand", E=3e4, nu=0.3, rho=1000.0, friction_angle=40.0)
    b.box("sand", lower=[0.1, 0.1], upper=[0.9, 0.25])
    b.rigid_body([[0.3, 0.15], [0.3, 0.45]], [[0, 1]], motion="scripted", velocity=[params.blade_speed, 0.0])
    return b.time(dt=dt, t_end=params.sand_t_end).build()


def rotor_scene(params):
    """A thin plate spinning at ``rotor_omega`` about its centre inside a jelly block resting on the floor."""
    b = _base(params, "cpic_rotor", penalty=1e3).material("jelly", "fixed_corotated", E=2e4, nu=0.3, rho=100.0)
    b.box("jelly", lower=[0.3, 0.1], upper=[0.7, 0.3])
    b.rigid_body([[0.44, 0.2], [0.56, 0.2]], [[0, 1]], motion="scripted", angular_velocity=params.rotor_omega)
    return b.time(dt=fixed_dt(params, 2e4, 100.0), t_end=params.rotor_t_end).build()


def ball_scene(params, exact, ghost_force=True):
    """A jelly ball at 1 m/s onto a free thin plate; no gravity, no walls, no pushing force, no penalty."""
    method = {"momentum_exact": True} if exact else {"pushing_force": 0.0}
    method["ghost_force"] = ghost_force
    b = _base(params, "cpic_ball", scheme="pic", gravity=False, walls="open", **method)
    b.material("jelly", "fixed_corotated", E=2e3, nu=0.3, rho=1.0)
    b.ball("jelly", center=[0.5, 0.62], radius=0.1, velocity=[0.0, -1.0])
    b.rigid_body([[0.3, 0.45], [0.7, 0.45]], [[0, 1]], motion="dynamic", density=0.05, gravity=False)
    return b.time(dt=fixed_dt(params, 2e3, 1.0), t_end=params.ball_t_end).build()


WEDGE = [[0.44, 0.06], [0.5, 0.4], [0.56, 0.06]]


def cut_scene(params):
    """A jelly block falling onto a fixed wedge blade whose edge is at (0.5, 0.4)."""
    b = _base(params, "cpic_cut", penalty=1e3).material("jelly", "fixed_corotated", E=2e4, nu=0.3, rho=100.0)
    b.box("jelly", lower=[0.35, 0.5], upper=[0.65, 0.6])
    b.rigid_body(WEDGE, [[0, 1], [1, 2]], motion="fixed")
    return b.time(dt=fixed_dt(params, 2e4, 100.0), t_end=params.cut_t_end).build()


def wedge_blade(edge_axis, top=0.4, foot=0.06, half_base=0.06, extent=(0.25, 0.75), index=0):
    """An open wedge blade: two planar faces meeting at a sharp top edge at height ``top`` over the line
    ``x = 0.5`` or ``z = 0.5``, running along ``edge_axis`` (0: x, 2: z) over ``extent``; the faces reach
    ``half_base`` to either side at height ``foot``. Four triangles, zero thickness, consistently oriented."""
    across = 2 - edge_axis
    vertices = []
    for offset, y in ((0.0, top), (-half_base, foot), (half_base, foot)):
        for e in extent:
            point = [0.0, y, 0.0]
            point[edge_axis], point[across] = e, 0.5 + offset
            vertices.append(point)
    return validate_trimesh(vertices, [[0, 2, 3], [0, 3, 1], [0, 1, 5], [0, 5, 4]], index=index)


def cut3d_scene(params):
    """A jelly block thrown down at 2 m/s onto two crossed fixed wedge blades (:func:`wedge_blade`) whose top edges
    cross at (0.5, 0.4, 0.5): the blades cut it into four pieces that slide down their faces (3D)."""
    b = (SceneBuilder(dim=3, name="cpic_cut3d").grid(size=1.0, cells=params.cut3d_cells)
         .method("mls", coupling="cpic", penalty=1e3).walls("separate", domain_exit="delete")
         .gravity([0.0, -params.g, 0.0]))
    b.material("jelly", "fixed_corotated", E=5e3, nu=0.3, rho=100.0)
    b.box("jelly", lower=[0.35, 0.42, 0.35], upper=[0.65, 0.52, 0.65], velocity=[0.0, -2.0, 0.0])
    for index, axis in enumerate((0, 2)):
        blade = wedge_blade(axis, index=index)
        b.rigid_body(blade.vertices, blade.triangles, motion="fixed")
    dt = 0.3 / params.cut3d_cells / (np.sqrt(5e3 / 100.0) + 4.0)  # CFL 0.3 with 4 m/s of motion
    return b.time(dt=dt, t_end=params.cut3d_t_end).build()


def friction_scene(params, ghost_force=True):
    """A block resting on a fixed segment, sliding at 1 m/s; friction ``mu`` on the segment's upper side."""
    b = _base(params, "cpic_friction", pushing_force=0.0, ghost_force=ghost_force)
    b.material("block", "fixed_corotated", E=1e5, nu=0.3, rho=1000.0)
    dx = 1.0 / params.cells
    b.box("block", lower=[0.15, 0.3 + 0.25 * dx], upper=[0.25, 0.3 + 0.25 * dx + 0.05], velocity=[1.0, 0.0])
    b.rigid_body([[0.05, 0.3], [0.95, 0.3]], [[0, 1]], motion="fixed", friction=params.mu)
    return b.time(dt=fixed_dt(params, 1e5, 1000.0), t_end=params.friction_t_end).build()


#: the sand wheel's source (Hu et al. 2018's 2D scene): centre, radius, velocity and end of emission; the sand
SOURCE = {"center": [0.6, 0.64], "radius": 0.05, "velocity": [-1.0, 0.0], "until": 2.5}
SAND = {"E": 3e4, "nu": 0.3, "rho": 1000.0, "friction_angle": 45.0}


def wheel_scene(params):
    r"""The sand wheel, after Hu et al. 2018's 2D scene on a coarser grid (docs/cpic.md, "The sand wheel").

    A ring (60 segments, radius 0.16) and 18 slanted blades between radii 0.136 and 0.24, pinned at
    (0.5, 0.35), free to turn, angular damping 2.7/s, shell density 100, slip with friction 0.4; the blades are
    welded to the ring. A sticky floor segment at y = 0.1. Sand (Drucker–Prager, friction angle 45°, no
    cohesion, ρ = 1000) enters as a disk of radius 0.05 at (0.6, 0.64) moving at (-1, 0) m/s, released every
    0.1 s until 2.5 s (the first release is the scene's body). No pushing force; the penalty is
    :math:`k = 1/\Delta t` (the reference's :math:`k\Delta t = 10^4 \cdot 10^{-4} = 1`).
    """
    dt = fixed_dt(params, SAND["E"] * (1 - SAND["nu"]) / ((1 + SAND["nu"]) * (1 - 2 * SAND["nu"])), SAND["rho"],
                  cells=params.wheel_cells)
    b = (SceneBuilder(dim=2, name="cpic_sand_wheel").grid(size=1.0, cells=params.wheel_cells)
         .method("mls", coupling="cpic", penalty=1.0 / dt, pushing_force=0.0, cpic_fit=params.wheel_fit)
         .walls("separate", domain_exit="delete").gravity([0.0, -params.g]))
    b.material("sand", "sand", **SAND)
    b.ball("sand", center=SOURCE["center"], radius=SOURCE["radius"], velocity=SOURCE["velocity"])
    data = add_sand_wheel(b).time(dt=dt, t_end=params.wheel_t_end).as_dict()
    interval = 2.0 * SOURCE["radius"] / np.linalg.norm(SOURCE["velocity"])
    data["emitters"] = [{"material": "sand", "center": SOURCE["center"], "radius": SOURCE["radius"],
                         "velocity": SOURCE["velocity"], "start": interval, "interval": interval,
                         "until": SOURCE["until"]}]
    return Scene.from_dict(data)


def wheel_omega_floor(scene):
    r"""The floor :math:`|\omega|` must stay above: a tenth of the wheel's driven rate :math:`\omega^*`.

    If the wheel took up the sand stream's tangential momentum at the blade tips, the stream would apply
    the torque :math:`\dot m\,|\mathbf v|\,R` (:math:`\dot m = \rho \pi r^2/\Delta t_{release}` the mass
    rate, :math:`|\mathbf v|` the release speed, :math:`R` the blades' outer radius), and the damping
    :math:`c I \omega` would balance it at :math:`\omega^* = \dot m |\mathbf v| R / (c I)` (:math:`I` the ring's
    and the blades' inertia). The check asks for at least :math:`\omega^*/10`: clearly turning, not a
    number a drifting or jittering wheel reaches.
    """
    source = scene.emitters[0]
    rho = scene.materials[source.body.material].rho
    mass_rate = rho * np.pi * source.body.params["radius"] ** 2 / source.interval
    speed = float(np.linalg.norm(source.body.params["velocity"]))
    inertia = sum(b.inertia for b in scene.rigid_bodies if b.motion == "dynamic")
    damping = scene.rigid_bodies[0].angular_damping
    return 0.1 * mass_rate * speed * SAND_WHEEL["blade_outer"] / (damping * inertia)


BLADE = [[0.5, 0.06], [0.5, 0.4]]  # the vertical cut line of the baselines


def baseline_scene(params, kind):
    """The jelly block of :func:`cut_scene` over the cut line :data:`BLADE`, cut the way ``kind`` says.

    ``"cpic"``: a fixed CPIC blade on the line; ``"level_set"``: a box collider half a cell thick around it;
    ``"remove"``, ``"soften"``: no blade (the particles are removed or softened by :func:`baseline_particles`).
    """
    method = {"coupling": "cpic", "penalty": 1e3} if kind == "cpic" else {}
    b = (SceneBuilder(dim=2, name=f"cpic_baseline_{kind}").grid(size=1.0, cells=params.cells).method("mls", **method)
         .walls("separate", domain_exit="delete").gravity([0.0, -params.g]))
    b.material("jelly", "fixed_corotated", E=2e4, nu=0.3, rho=100.0)
    b.material("soft", "fixed_corotated", E=2.0, nu=0.3, rho=100.0)  # 10^-4 of the jelly's stiffness
    b.box("jelly", lower=[0.35, 0.5], upper=[0.65, 0.6])
    if kind == "cpic":
        b.rigid_body(BLADE, [[0, 1]], motion="fixed")
    if kind == "level_set":
        half = 0.25 / params.cells
        b.collider("box", lower=[0.5 - half, BLADE[0][1]], upper=[0.5 + half, BLADE[1][1]])
    return b.time(dt=fixed_dt(params, 2e4, 100.0), t_end=params.cut_t_end).build()


def baseline_particles(scene, kind, width):
    """The block's particles for baseline ``kind``: those within ``width / 2`` cells of the line removed
    (``"remove"``) or given the soft material (``"soften"``); all of them, unchanged, otherwise."""
    particles = sample_particles(scene)
    strip = np.abs(particles.x[:, 0] - BLADE[0][0]) <= 0.5 * width * scene.grid.dx
    if kind == "remove":
        return particles.select(~strip)
    if kind == "soften":
        particles.material[strip] = 1
    return particles


#: the baselines run (default and full presets): ``(kind, width in cells)`` of :func:`baseline_scene`
BASELINES = (("cpic", 0.0), ("level_set", 0.0), ("remove", 1.0), ("remove", 1.5), ("soften", 2.0))


def fixed_dt(params, E, rho, cfl=0.3, cells=None):
    """A fixed step at CFL number ``cfl`` for the elastic wave speed of ``E``, ``rho`` (plus 2 m/s of motion) on a
    grid of ``cells`` (default ``params.cells``) across the unit domain."""
    return cfl * (1.0 / (cells or params.cells)) / (np.sqrt(E / rho) + 2.0)

