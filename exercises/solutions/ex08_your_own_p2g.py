r"""Exercise 8: write your own P2G, particle by particle, and pass the conformance harness.

Task. Implement the P2G of ``docs/mpm_cycle.md`` (equations ``eq-p2g-mass``, ``eq-p2g-momentum`` and
``eq-internal-force``) for the quadratic B-spline in 2D, as a plain loop over particles and their 3 × 3
nodes, the way a C or GPU code would, for PIC and APIC with either force. Check it with
``mpmref.conformance.check`` (``docs/conformance.md``) at the harness's float64 tolerance.

Prediction. The loop does the reference's arithmetic in another order (one particle at a time instead of
one stencil offset at a time), so it agrees to round-off: relative errors of order :math:`10^{-16}`, far
inside the harness's float64 tolerance.

Worked solution. For particle :math:`p` with :math:`\xi = (x_p - o)/\Delta x`, the stencil's first node
is :math:`b = \lfloor \xi - \tfrac12 \rfloor` and :math:`f = \xi - b`; the per-axis weights of nodes
:math:`b, b+1, b+2` are :math:`\tfrac12(\tfrac32 - f)^2`, :math:`\tfrac34 - (f - 1)^2`,
:math:`\tfrac12(f - \tfrac12)^2`, and their derivatives :math:`f - \tfrac32`, :math:`-2(f - 1)`,
:math:`f - \tfrac12` (per cell). The stress comes from the reference (the stage computes it itself);
everything else is written out below. Only the cases this code claims (quadratic kernel; ``pic`` or
``apic``) are checked.
"""

import numpy as np

from mpmref.backends import make_backend
from mpmref.conformance import check, make_cases
from mpmref.state import GridState


def quadratic_weights(f):
    """Weights and derivatives (per cell) of the three nodes b, b+1, b+2 for the offset ``f`` in [0.5, 1.5)."""
    w = np.array([0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2])
    dw = np.array([f - 1.5, -2.0 * (f - 1.0), f - 0.5])
    return w, dw


def my_p2g(scene, particles):
    grid, spec = scene.grid, scene.transfer
    dx, origin = grid.dx, np.asarray(grid.origin)
    tau = make_backend("numpy", scene).stress(particles)
    mass = np.zeros(grid.n_nodes)
    momentum = np.zeros((grid.n_nodes, 2))
    force = np.zeros((grid.n_nodes, 2))
    for p in range(len(particles.x)):
        xi = (particles.x[p] - origin) / dx
        base = np.floor(xi - 0.5).astype(int)
        (wx, dwx), (wy, dwy) = quadratic_weights(xi[0] - base[0]), quadratic_weights(xi[1] - base[1])
        C = particles.C[p] if spec.affine else np.zeros((2, 2))
        for a in range(3):
            for b in range(3):
                node = base + (a, b)
                i = node @ grid.strides
                w = wx[a] * wy[b]
                d = (node - xi) * dx                                   # x_i - x_p
                if spec.force == "mls":
                    g = w * d / (0.25 * dx * dx)                       # w_ip D_p^-1 (x_i - x_p)
                else:
                    g = np.array([dwx[a] * wy[b], wx[a] * dwy[b]]) / dx  # grad w_ip
                mass[i] += w * particles.mass[p]
                momentum[i] += w * particles.mass[p] * (particles.v[p] + C @ d)
                force[i] -= particles.vol0[p] * tau[p] @ g
    return GridState(mass, momentum, force)


def claimed(case):
    method = case.scene_dict["method"]
    return method.get("kernel") == "quadratic" and method.get("scheme") in ("pic", "apic")


def solve():
    cases = [case for case in make_cases(dims=(2,), stages=("p2g",)) if claimed(case)]
    report = check({"p2g": my_p2g}, cases)
    assert len(report.results) >= 4 and report.passed, report.table()
    assert report.worst().error < 1e-14
    return {result.case.variant: result.error for result in report.results}


if __name__ == "__main__":
    print(solve())
