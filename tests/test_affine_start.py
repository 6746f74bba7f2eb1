"""A body's affine initial velocity, ``velocity_gradient`` (docs/scenes.md): the field it declares, the consistent
affine matrix the affine schemes start from, and why that start matters (one transfer cycle changes nothing)."""

import numpy as np
import pytest

from mpmref import SceneBuilder, SceneError, Simulation
from mpmref.steppers import substep

G = [[0.8, 0.3], [-0.1, 0.8]]     # a breathing (0.8 I) plus a shear
SPIN = 2.0
CENTER = [0.5, 0.5]


def disk(scheme, dim=2, **body):
    center = CENTER + [0.5] * (dim - 2)
    return (SceneBuilder(dim=dim, name="breathing").grid(size=1.0, cells=16).method(scheme)
            .material("rubber", "neo_hookean", E=1e3, nu=0.3, rho=1.0)
            .ball("rubber", center=center, radius=0.2, **body).walls("open").time(dt=1e-3).build())


@pytest.mark.parametrize("scheme", ["apic", "polypic", "mls"])
def test_apic_polypic_and_mls_start_with_c_equal_to_the_declared_gradient(scheme):
    sim = Simulation(disk(scheme, velocity_gradient=G, velocity=[0.1, -0.2], rotation_center=CENTER))
    assert np.array_equal(sim.C, np.broadcast_to(np.array(G), sim.C.shape))
    assert np.allclose(sim.v, [0.1, -0.2] + (sim.x - CENTER) @ np.array(G).T, rtol=0, atol=1e-15)


def test_the_gradient_adds_to_the_spin_in_velocity_and_in_c():
    """v = v0 + omega x (x - c) + G (x - c) and C = W(omega) + G, W(omega) = [[0, -omega], [omega, 0]]."""
    sim = Simulation(disk("apic", velocity_gradient=G, angular_velocity=SPIN, rotation_center=CENTER))
    grad = np.array(G) + [[0.0, -SPIN], [SPIN, 0.0]]
    assert np.array_equal(sim.C[0], grad)
    r = sim.x - CENTER
    assert np.allclose(sim.v, r @ grad.T, rtol=0, atol=1e-15)
    assert np.allclose(sim.v - r @ np.array(G).T, SPIN * np.stack([-r[:, 1], r[:, 0]], axis=1), rtol=0, atol=1e-15)


def test_in_3d_the_gradient_and_the_spin_vector_add():
    omega, grad = np.array([0.0, 0.0, 1.5]), np.diag([0.5, 0.5, 0.5])
    sim = Simulation(disk("apic", dim=3, velocity_gradient=grad.tolist(), angular_velocity=omega.tolist()))
    expected = grad + [[0.0, -1.5, 0.0], [1.5, 0.0, 0.0], [0.0, 0.0, 0.0]]
    assert np.array_equal(sim.C[0], expected)


def transfer_cycle(sim):
    """Particle kinetic energy (velocity and affine parts) before and after one P2G, grid update with Δt = 0,
    G2P; the particles after it."""
    energy = lambda: sim.diagnostics()["kinetic"] + sim.diagnostics()["kinetic_affine"]
    before = energy()
    sim.particles = substep(sim.backend, sim.particles, 0.0, sim.time)
    return before, energy()


@pytest.mark.parametrize("scheme", ["apic", "polypic", "mls"])
def test_the_consistent_start_is_a_fixed_point_of_the_transfers(scheme):
    """With C_p = grad v, P2G gives every node v(x_i) and G2P returns v_p and C_p unchanged (round-off): an
    affine field is represented exactly, so the first transfer neither dissipates nor creates energy."""
    sim = Simulation(disk(scheme, velocity_gradient=G, angular_velocity=SPIN))
    v0, C0 = sim.v.copy(), sim.C.copy()
    before, after = transfer_cycle(sim)
    scale = np.abs(v0).max()
    assert np.abs(sim.v - v0).max() < 1e-13 * scale
    assert np.abs(sim.C - C0).max() < 1e-12 * np.abs(C0).max()
    assert abs(after - before) < 1e-12 * before
    if scheme == "polypic":
        assert np.abs(sim.particles.modes).max() < 1e-12 * scale / sim.scene.grid.dx ** 2


def test_setting_v_by_hand_and_forgetting_c_is_not_a_fixed_point():
    """The hand-made start the scene key replaces: v set to the same field, C left at zero. P2G then averages
    v_p without their affine part, which is exact only where a node's particles surround it symmetrically: the
    first cycle rebuilds C from the grid, off at the rim, moves v there and changes the kinetic energy (by
    about 9 % here), where the consistent start changes nothing beyond round-off (the test above)."""
    sim = Simulation(disk("apic"))
    sim.v = v0 = (sim.x - CENTER) @ np.array(G).T
    before, after = transfer_cycle(sim)
    assert abs(after - before) > 1e-2 * before
    assert np.abs(sim.C - np.array(G)).max() > 0.1 * np.abs(G).max()
    assert np.abs(sim.v - v0).max() > 1e-2 * np.abs(v0).max()


@pytest.mark.parametrize("value", [[[1.0, 0.0]], [[1.0, 0.0], [0.0]], [[1.0, 0.0], [0.0, float("nan")]], 2.0,
                                   [[1.0, 0.0], [0.0, True]]])
def test_a_gradient_that_is_not_a_finite_d_by_d_matrix_is_refused_naming_it(value):
    with pytest.raises(SceneError) as info:
        disk("apic", velocity_gradient=value)
    assert info.value.field == "bodies[0].velocity_gradient" and "2 x 2 matrix" in info.value.allowed
