r"""Exercise 6: internal forces exert no net force and, for a symmetric stress, no net torque.

Task. The nodal force is :math:`f_i = -\sum_p V_p^0\,\tau_p\,g_{ip}` (``docs/mpm_cycle.md``, equation
``eq-internal-force``). Predict :math:`\sum_i f_i` and the torque :math:`\sum_i x_i \times f_i` for both
force discretisations, first for symmetric Kirchhoff stresses, then for a deliberately non-symmetric
one, and check the predictions with the reference P2G.

Prediction. :math:`\sum_i g_{ip} = 0` for both weights, so :math:`\sum_i f_i = 0`. Writing
:math:`x_i = x_p + (x_i - x_p)` and using :math:`\sum_i (x_i - x_p) g_{ip}^T = I`, the torque in 2D is
:math:`-\sum_p V_p^0\,(\tau_{p,yx} - \tau_{p,xy})`: zero for a symmetric stress, and exactly that
number otherwise. A material whose stress is not symmetric would spin bodies up by itself.

Worked solution. Call ``mpmref.backends.numpy.transfers.p2g`` with a chosen ``tau`` and sum the forces.
"""

import numpy as np

from mpmref import SceneBuilder, Simulation
from mpmref.backends.numpy import transfers


def scene(force):
    return (SceneBuilder(dim=2, name="balance").grid(size=1.0, cells=16).method("apic", force=force)
            .material("m", "fixed_corotated", E=1e3).box("m", lower=[0.3, 0.3], upper=[0.7, 0.6])
            .time(dt=1e-4).build())


def net_force_and_torque(sc, particles, tau):
    gs = transfers.p2g(particles, tau, sc.grid, sc.kernel, sc.transfer)
    x = sc.grid.node_positions()
    torque = np.sum(x[:, 0] * gs.force[:, 1] - x[:, 1] * gs.force[:, 0])
    return gs.force.sum(axis=0), torque, np.abs(gs.force).max()


def solve():
    rng = np.random.default_rng(6)
    out = {}
    for force in ("mls", "classic"):
        sc = scene(force)
        p = Simulation(sc).particles
        A = rng.standard_normal((len(p.x), 2, 2))
        symmetric = A + A.transpose(0, 2, 1)
        skew = A - A.transpose(0, 2, 1)
        for name, tau in (("symmetric", symmetric), ("non-symmetric", symmetric + skew)):
            total, torque, scale = net_force_and_torque(sc, p, tau)
            predicted = -np.sum(p.vol0 * (tau[:, 1, 0] - tau[:, 0, 1]))
            assert np.abs(total).max() < 1e-12 * scale * len(p.x), (force, name, total)
            assert abs(torque - predicted) < 1e-12 * scale * len(p.x), (force, name, torque, predicted)
            out[(force, name)] = torque
        assert abs(out[(force, "non-symmetric")]) > 1e3 * abs(out[(force, "symmetric")])
    return out


if __name__ == "__main__":
    print(solve())
