r"""Exercise 9: the CFL time step of compressed material.

Task. With ``time.cfl`` = :math:`C`, mpmref takes :math:`\Delta t = C\,\Delta x / \max_p (c_p + |v_p|)` with
each particle's wave speed in its current state (``docs/mpm_cycle.md``, equation ``eq-cfl``). Predict the
step of a resting Tait fluid (:math:`\gamma = 7`) and of a resting fixed-corotated block, first at rest
and then uniformly compressed to :math:`J = 0.9`; measure the step mpmref takes.

Prediction. Fluid: :math:`c_p^2 = \gamma K / (\rho_0 J^{\gamma - 1})`, so the step shrinks by
:math:`J^{(\gamma-1)/2} = 0.9^3 = 0.729`. Solid: :math:`c_p^2 = 4\mu J/(3\rho_0) + K(1 - \ln J)/\rho_0`
with :math:`K = \tfrac23\mu + \lambda`; at :math:`J = 1` this is the P-wave speed. A rest-state wave speed
would overestimate the stable step of compressed fluid by 37 %.

Worked solution. Set the particles' state (``sim.J`` for the fluid, ``sim.F`` for the solid), take one
step and read ``sim.last_dt``.
"""

import numpy as np

from mpmref import SceneBuilder, Simulation
from mpmref.physics.materials import lame_parameters

CFL, CELLS, J = 0.5, 32, 0.9


def first_step(material, **params):
    scene = (SceneBuilder(dim=2, name="cfl").grid(size=1.0, cells=CELLS)
             .material("m", material, rho=1.0, **params).box("m", lower=[0.3, 0.3], upper=[0.6, 0.6])
             .walls("open").time(cfl=CFL).build())
    return Simulation(scene)


def step_at(sim, **state):
    for name, value in state.items():
        setattr(sim, name, value)
    sim.step()
    return sim.last_dt


def solve():
    dx, K, gamma = 1.0 / CELLS, 100.0, 7.0
    fluid_rest = step_at(first_step("fluid", K=K, gamma=gamma))
    fluid = first_step("fluid", K=K, gamma=gamma)
    fluid_compressed = step_at(fluid, J=np.full(len(fluid.x), J))
    assert np.isclose(fluid_rest, CFL * dx / np.sqrt(gamma * K), rtol=1e-12)
    assert np.isclose(fluid_compressed / fluid_rest, J ** ((gamma - 1) / 2), rtol=1e-12)

    E, nu = 1e3, 0.3
    mu, lam = (float(v) for v in lame_parameters(E, nu))
    solid_rest = step_at(first_step("fixed_corotated", E=E, nu=nu))
    solid = first_step("fixed_corotated", E=E, nu=nu)
    solid_compressed = step_at(solid, F=np.broadcast_to(np.sqrt(J) * np.eye(2), solid.F.shape).copy())
    bulk = 2.0 / 3.0 * mu + lam
    c = np.sqrt(4 * mu * J / 3 + bulk * (1 - np.log(J)))
    assert np.isclose(solid_rest, CFL * dx / np.sqrt(lam + 2 * mu), rtol=1e-12)
    assert np.isclose(solid_compressed, CFL * dx / c, rtol=1e-12)
    return {"fluid_ratio": fluid_compressed / fluid_rest, "solid_ratio": solid_compressed / solid_rest}


if __name__ == "__main__":
    print(solve())
