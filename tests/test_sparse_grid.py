"""The Numba backend's sparse grid (mpmref/backends/numba/sparse.py): which blocks are active, that a step on it
is the step on the dense grid, and that its cost follows the body, not the domain.

Agreement of each stage with the NumPy reference is the conformance harness's job (its P2G and G2P cases run
the sparse kernels, scattered to or gathered from the dense node arrays); these tests cover what it does not.
"""

import numpy as np
import pytest

from mpmref import SceneBuilder, Simulation
from mpmref.backends import make_backend
from mpmref.scene.sampling import sample_particles
from mpmref.steppers import Hooks, substep


def block_scene(cells, lower, upper, walls="separate", colliders=False, region="active"):
    """A 2D elastic block (8 cells per body side at dx = 1/32) in a square domain of ``cells`` cells."""
    dx = 1.0 / 32
    b = (SceneBuilder(dim=2, name="block").grid(size=cells * dx, cells=cells).method("mls")
         .material("jelly", "fixed_corotated", E=1e3, nu=0.3, rho=1.0)
         .box("jelly", lower=[c * dx for c in lower], upper=[c * dx for c in upper], ppc=4, sampling="regular",
              velocity=[0.3, -0.5])
         .gravity([0.0, -9.8]).time(dt=1e-4).output(grid=True, grid_region=region))
    b.walls(walls, friction=0.4 if walls == "separate" else 0.0, width=3)
    if colliders:
        b.collider("disk", center=[(lower[0] + upper[0]) / 2 * dx, lower[1] * dx], radius=2 * dx,
                   type="separate", friction=0.2)
    return b.build()


def stirred(particles, seed=5):
    """The particles with random velocities and affine matrices, so that every node gets a generic value."""
    rng = np.random.default_rng(seed)
    return particles.with_(v=particles.v + rng.standard_normal(particles.v.shape),
                           C=rng.standard_normal(particles.C.shape))


def test_active_blocks_are_the_owner_blocks_and_their_upper_neighbours():
    """Every node a particle's stencil reaches lies in an active block, and only owner blocks and their upper
    neighbours are active (the rule of the module doc), counted independently from the particles here."""
    scene = block_scene(64, (20, 12), (29, 21))
    backend = make_backend("numba", scene)
    particles = sample_particles(scene)
    layout = backend.prepare(particles).layout
    B = scene.grid.block
    base = np.floor((particles.x - scene.grid.origin) / scene.grid.dx - 0.5).astype(int)  # quadratic base node
    owners = {tuple(b) for b in base // B}
    expected = {(o[0] + i, o[1] + j) for o in owners for i in (0, 1) for j in (0, 1)}
    assert {tuple(b) for b in layout.blocks} == expected
    reached = {tuple((b + (i, j)) // B) for b in base for i in range(3) for j in range(3)}
    assert reached <= expected
    assert layout.n_rows == len(expected) * B**2 < scene.grid.n_nodes / 10


def test_dense_and_sparse_round_trip():
    scene = block_scene(32, (10, 10), (18, 18))
    layout = make_backend("numba", scene).prepare(sample_particles(scene)).layout
    dense = np.random.default_rng(1).standard_normal((scene.grid.n_nodes, 2))
    rows = layout.from_dense(dense)
    back = layout.to_dense(rows)
    kept = np.zeros(scene.grid.n_nodes, dtype=bool)
    kept[layout.dense_index()] = True
    assert np.array_equal(back[kept], dense[kept]) and not back[~kept].any()
    assert not rows[~layout.inside].any()  # padding rows beyond the grid hold nothing


@pytest.mark.parametrize("walls, colliders", [("sticky", False), ("slip", False), ("separate", True)])
def test_grid_update_on_the_active_blocks_gives_the_dense_grid_update_bit_for_bit(walls, colliders):
    """The block loop and the dense loop share the per-node arithmetic: same bits at every node, with the body
    in the walls' bands and a collider."""
    scene = block_scene(32, (1, 1), (12, 9), walls=walls, colliders=colliders)
    backend = make_backend("numba", scene)
    particles = stirred(sample_particles(scene))
    prepared = backend.prepare(particles)
    sparse = backend.p2g(particles, prepared)
    dense = sparse.dense()
    assert sparse.layout is prepared.layout and dense.layout is None
    v_sparse, vt_sparse = (a.copy() for a in backend.grid_update(sparse, 1e-4, 0.01))
    v_dense, vt_dense = backend.grid_update(dense, 1e-4, 0.01)
    assert np.array_equal(sparse.layout.to_dense(v_sparse), v_dense)
    assert np.array_equal(sparse.layout.to_dense(vt_sparse), vt_dense)
    assert np.abs(v_dense - vt_dense).max() > 0


def test_a_body_in_a_large_domain_steps_as_in_a_tight_one_on_as_many_rows():
    """The same body, 3 cells from the origin and far from the far walls: 10 steps in a 16-cell and a 128-cell
    domain give the same bits, on the same number of node rows."""
    tight, large = (block_scene(cells, (4, 5), (12, 11), walls="slip") for cells in (16, 128))
    results, rows = [], []
    for scene in (tight, large):
        backend = make_backend("numba", scene)
        particles = sample_particles(scene)
        rows.append(backend.prepare(particles).layout.n_rows)
        for k in range(10):
            particles = substep(backend, particles, 1e-4, k * 1e-4)
        results.append(particles)
    assert rows[0] == rows[1]
    for name, array in results[0].arrays().items():
        assert np.array_equal(array, results[1].arrays()[name]), name


def test_hooks_see_dense_arrays_and_their_changes_reach_the_sparse_step():
    """A body force and a grid fold (zero the momentum of the nodes of the lowest 12 node rows) on a sparse
    grid state: one step agrees with the reference's to 1e-12."""
    scene = block_scene(32, (10, 10), (18, 18))

    def fold(gs, grid):
        gs.momentum.reshape(grid.node_shape + (grid.dim,))[:, :12] = 0.0

    hooks = Hooks(body_force=lambda p, t: np.tile([2.0, 1.0], (p.n, 1)), grid_folds=(fold,))
    particles = stirred(sample_particles(scene))
    reference = substep(make_backend("numpy", scene), particles, 1e-4, 0.0, hooks)
    fast = substep(make_backend("numba", scene), particles, 1e-4, 0.0, hooks)
    plain = substep(make_backend("numpy", scene), particles, 1e-4, 0.0)
    for name in ("x", "v", "C", "F"):
        scale = np.abs(getattr(reference, name)).max()
        assert np.abs(getattr(fast, name) - getattr(reference, name)).max() <= 1e-12 * scale, name
    assert np.abs(plain.v - reference.v).max() > 1e-3  # the hooks did change the step


def test_grid_output_region_is_the_block_box_of_the_massive_nodes(backend):
    """``output.grid_region = "active"``: the smallest box of whole blocks around the nodes with mass, holding all
    the mass; ``"all"``: every node, the same values."""
    scene = block_scene(64, (20, 12), (29, 21))
    sim = Simulation(scene, backend=backend, out_dir=None)
    first, shape, data = sim.grid_data()
    assert first == (16, 8) and shape == (16, 16)  # nodes 19..30 and 11..22 have mass: blocks 4..7 and 2..5
    every = Simulation(block_scene(64, (20, 12), (29, 21), region="all"), backend=backend, out_dir=None)
    first_all, shape_all, data_all = every.grid_data()
    assert first_all == (0, 0) and shape_all == scene.grid.node_shape
    mass_all = data_all["mass"].reshape(shape_all)
    assert np.array_equal(mass_all[16:32, 8:24], data["mass"].reshape(shape))
    assert data["mass"].sum() == pytest.approx(mass_all.sum(), rel=1e-14)
