r"""Exercise 7: a block sliding on a frictional floor (the boundary projection of talk Eq. 25).

Task. An elastic block rests on a ``separate`` floor with Coulomb friction :math:`\mu` and is given a
horizontal velocity :math:`v_0` (``docs/mpm_cycle.md``, "Boundary conditions", equation
``eq-wall-projection``). Predict how its mean horizontal velocity changes with time, then measure it.

Prediction. Gravity presses the floor band's nodes into the wall: each step adds :math:`-g\Delta t` to
their normal velocity, which the projection removes, and the sliding branch then reduces the tangential
velocity by :math:`\mu g \Delta t`. Only the nodes that touch the floor feel it, but the elastic block
transmits the traction, so once sliding is established the block as a whole decelerates at
:math:`a = \mu g` (as for a rigid block on a level floor): :math:`\bar v(t) = v_0 - \mu g t` until it
stops. Without friction (:math:`\mu = 0`) it keeps :math:`v_0`.

Worked solution. Track the mass-weighted mean horizontal velocity. The elastic block bounces on the
floor, which modulates the normal force and with it the friction from step to step (fit over a third of
the run and the slope swings between about 4 and 6 for :math:`\mu g = 4.9`), but on average the floor
carries the weight: the mean deceleration over the whole run, :math:`(v_0 - \bar v(T))/T`, is
:math:`\mu g` within 15 %.
"""

import numpy as np

from mpmref import SceneBuilder, Simulation

G, V0, STEPS, DT = 9.8, 1.0, 400, 2e-4


def sliding_block(mu):
    scene = (SceneBuilder(dim=2, name="slide").grid(size=1.0, cells=32)
             .material("m", "fixed_corotated", E=1e4, nu=0.3, rho=1.0)
             .box("m", lower=[0.2, 0.1], upper=[0.4, 0.2], velocity=[V0, 0.0])
             .gravity([0.0, -G]).walls("separate", friction=mu).time(dt=DT).build())
    return Simulation(scene)


def mean_velocity_history(sim):
    history = []
    for _ in range(STEPS):
        sim.step()
        history.append(np.average(sim.v[:, 0], weights=sim.mass))
    return np.array(history)


def solve():
    mu = 0.5
    v = mean_velocity_history(sliding_block(mu))
    deceleration = (V0 - v[-1]) / (STEPS * DT)
    assert v[-1] > 0.0, "the block stopped: the run is too long to measure the sliding phase"
    assert abs(deceleration / (mu * G) - 1.0) < 0.15, deceleration
    frictionless = mean_velocity_history(sliding_block(0.0))
    assert abs(frictionless[-1] - V0) < 0.02 * V0
    return {"measured_deceleration": deceleration, "predicted": mu * G, "frictionless_final_v": frictionless[-1]}


if __name__ == "__main__":
    print(solve())
