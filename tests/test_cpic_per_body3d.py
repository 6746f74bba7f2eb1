"""The per-body fit of CPIC in 3D (``method.cpic_fit = "per_body"``, docs/cpic.md "Per-body fit"): the wedge of
tests/test_cpic_per_body.py with a horizontal plate for the wall and a vertical plate for the blade. The reference
(:func:`mpmref.physics.cdf.reconstruct_per_body`) gives each plate's own distance and normal; the conformance case
``*-mls-mls-quadratic-per-body`` exercises the per-body fit on most particles it tags twice, and, in the slow
set, the compiled 3D stages follow the reference on it (tests/test_cpic_numba3d.py)."""

import numpy as np

from mpmref.conformance import CPIC_CONFORMANCE_STAGES, make_cases
from mpmref.physics.cdf import build_cdf, reconstruct, reconstruct_per_body, update_tags
from mpmref.rigid.trimesh import rectangle

N = 32
DX = 1.0 / N
WEDGE = [0.5 + 0.6 * DX, 0.5 + 0.3 * DX, 0.5]  # 0.3 dx above the plate, 0.6 dx right of the blade


def _wedge_fits():
    plate = rectangle(center=[0.5, 0.5, 0.5], u=[0.2, 0.0, 0.0], v=[0.0, 0.0, 0.2])  # the wall y = 0.5
    blade = rectangle(center=[0.5, 0.55 - 0.5 * DX, 0.5], u=[0.0, 0.05 + 0.5 * DX, 0.0], v=[0.0, 0.0, 0.2], index=1)
    cdf = build_cdf([plate, blade], shape=(N + 1,) * 3, origin=(0.0, 0.0, 0.0), dx=DX)
    x = np.array([WEDGE])
    none = np.zeros((1, 2), dtype=bool)
    A, T = update_tags(cdf, x, none, none)
    return A, reconstruct(cdf, x, A, T), reconstruct_per_body(cdf, x, A, T)


def test_a_3d_wedge_particle_gets_each_plates_own_distance_and_normal():
    """A plane's signed distance is linear, so each plate's own fit is exact: phi = 0.3 dx and n = ±y for the wall,
    0.6 dx and n = ±x for the blade (the sign is the side the particle is tagged on); the single fit mixes them."""
    A, (phi, normal, near), (phi_r, normal_r, near_r) = _wedge_fits()
    assert A[0].tolist() == [True, True] and near_r[0].tolist() == [True, True]
    np.testing.assert_allclose(np.abs(phi_r[0]) / DX, [0.3, 0.6], atol=1e-9)
    np.testing.assert_allclose(np.abs(normal_r[0]), [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], atol=1e-9)
    assert near[0] and np.degrees(np.arccos(min(abs(normal[0, 1]), 1.0))) > 20.0


def test_the_3d_per_body_cases_exercise_the_per_body_fit():
    """Particles of the 3D per-body case that two or more bodies tag get accepted fits per body (the reference's
    tags stage; measured: 26 of the 122 tagged twice or more have two or more accepted fits): the case tests the
    per-body branches of the compiled tags, P2G and G2P."""
    case = next(c for c in make_cases(dims=(3,), stages=CPIC_CONFORMANCE_STAGES)
                if c.stage == "cpic_tags" and c.variant == "mls-mls-quadratic-per-body")
    out = case.reference(case.inputs())
    several = out["tag_A"].sum(axis=1) >= 2
    accepted = out["fit_near"].sum(axis=1) >= 2
    assert several.sum() >= 50 and (several & accepted).sum() >= 10
    assert np.all(out["fit_near"][~several] == 0)
