"""The per-body fit of CPIC (``method.cpic_fit = "per_body"``, docs/cpic.md "Per-body fit"): a particle in the
wedge where a blade meets a wall gets each body's own distance and normal (the single fit mixes them), the ghost
velocity across the wall then stops its approach to the wall, and with one body nothing changes, bit for bit."""

import numpy as np
import pytest

from mpmref import SceneBuilder, Simulation
from mpmref.backends import make_backend
from mpmref.errors import SceneError
from mpmref.physics.cdf import build_cdf, reconstruct, reconstruct_per_body, update_tags
from mpmref.rigid.polyline import validate_polyline

DX = 1.0 / 64
WALL = [[0.3, 0.5], [0.7, 0.5]]        # the "ring": a horizontal wall, side 0 above
BLADE = [[0.5, 0.5 - DX], [0.5, 0.6]]  # a blade meeting it, reaching one cell past it (as the wheel's blades do)
WEDGE = [0.5 + 0.6 * DX, 0.5 + 0.3 * DX]  # 0.3 dx above the wall, 0.6 dx right of the blade


def _wedge_fits():
    shapes = [validate_polyline(WALL, [[0, 1]]), validate_polyline(BLADE, [[0, 1]])]
    cdf = build_cdf(shapes, shape=(65, 65), origin=(0.0, 0.0), dx=DX)
    x = np.array([WEDGE])
    none = np.zeros((1, 2), dtype=bool)
    A, T = update_tags(cdf, x, none, none)
    return A, reconstruct(cdf, x, A, T), reconstruct_per_body(cdf, x, A, T)


def test_a_wedge_particle_gets_each_bodys_own_distance_and_normal():
    """Each body's signed distance is linear near a straight segment, so its own fit is exact: phi = 0.3 dx and
    n = (0, 1) for the wall, 0.6 dx and (1, 0) for the blade. The single fit mixes them: its normal is off the
    wall's by tens of degrees, the diagnosis of the sand wheel's ring (docs/cpic.md)."""
    A, (phi, normal, near), (phi_r, normal_r, near_r) = _wedge_fits()
    assert A[0].tolist() == [True, True] and near_r[0].tolist() == [True, True]
    np.testing.assert_allclose(phi_r[0] / DX, [0.3, 0.6], atol=1e-9)
    np.testing.assert_allclose(normal_r[0], [[0.0, 1.0], [1.0, 0.0]], atol=1e-9)
    assert near[0] and np.degrees(np.arccos(normal[0] @ [0.0, 1.0])) > 20.0


def _wedge_scene(fit, bodies=(WALL, BLADE)):
    b = (SceneBuilder(dim=2).grid(size=1.0, cells=64).method("pic", coupling="cpic", cpic_fit=fit)
         .material("jelly", "fixed_corotated", E=1e3, rho=1.0)
         .ball("jelly", center=[0.5 + 2 * DX, 0.5 + 2 * DX], radius=1.5 * DX, velocity=[0.0, -1.0])
         .walls("open").gravity([0.0, 0.0]).time(dt=1e-4))
    for vertices in bodies:
        b.rigid_body(vertices, [[0, 1]], type="slip", friction=0.0)
    return b.build()


def test_the_ghost_velocity_across_the_wall_stops_the_approach_only_with_the_per_body_fit():
    """A wedge particle moving into the wall at 1 m/s: at the nodes across the wall (incompatible through the wall
    alone) the slip projection against the wall's own normal leaves no velocity into the wall; against the single
    fit's mixed normal part of the approach is seen as tangential and kept."""
    into_wall = {}
    for fit in ("single", "per_body"):
        scene = _wedge_scene(fit)
        backend = make_backend("numpy", scene)
        sim = Simulation(scene)
        particles = sim.state.particles
        particles = particles.with_(x=np.tile(WEDGE, (particles.n, 1)), v=np.tile([0.0, -1.0], (particles.n, 1)))
        particles, contact = backend.cpic_contact(particles, backend.prepare(particles), sim.state.rigid, 1e-4)
        across = ~contact.compatible[:, 0] & (contact.node_x[:, 0, 1] < 0.5) & (contact.node_x[:, 0, 0] > 0.5)
        assert across.sum() >= 1
        into_wall[fit] = -contact.ghost[across, 0, 1].min()
    assert into_wall["per_body"] <= 1e-12
    assert into_wall["single"] > 0.1


def test_with_one_body_the_per_body_fit_changes_nothing_bitwise():
    """Particles near fewer than two bodies keep the single fit: a jelly ball hitting one wall runs bit for bit the
    same with either option (positions, velocities, deformation and the wall's state)."""
    runs = {}
    for fit in ("single", "per_body"):
        sim = Simulation(_wedge_scene(fit, bodies=(WALL,)))
        sim.run(steps=30)
        runs[fit] = sim
    a, b = runs["single"], runs["per_body"]
    assert a.state.particles.near.any()  # the ball reached the wall
    for name in ("x", "v", "F", "phi", "normal"):
        assert np.array_equal(getattr(a.state.particles, name), getattr(b.state.particles, name)), name
    assert np.array_equal(a.state.rigid.impulse, b.state.rigid.impulse)


def test_cpic_fit_is_validated():
    with pytest.raises(SceneError, match="method.cpic_fit.*'single', 'per_body'"):
        _wedge_scene("both")
