r"""Exercise 3: break the affine term of P2G and see which check fails.

Task. P2G scatters :math:`(mv)_i = \sum_p w_{ip} m_p (v_p + C_p (x_i - x_p))` (``docs/mpm_cycle.md``,
equation ``eq-p2g-momentum``). Write a "backend" whose P2G forgets :math:`C_p` (the bug of setting the
affine matrix to zero before the scatter), run it through the conformance harness on the P2G stage,
and predict which cases fail, and on which output (``grid_mass``, ``grid_momentum``, ``grid_force``).

Prediction. Mass never involves :math:`C_p`, so it stays exact. The affine term adds no net momentum
(:math:`\sum_i w_{ip}(x_i - x_p) = 0`), but it changes the momentum of each node: the ``grid_momentum``
output fails, in exactly the cases whose scheme carries :math:`C_p` (``apic``, ``mls``, ``polypic``);
``pic`` and ``flip`` have no :math:`C_p` and pass. The internal force does not use :math:`C_p` either.

Worked solution. The harness takes a dict of stage callables; the broken stage calls the reference
P2G on a copy of the particles with ``C = 0``.
"""

import numpy as np

from mpmref.backends import make_backend
from mpmref.conformance import check, make_cases

AFFINE = ("apic", "mls", "polypic")


def p2g_without_affine_term(scene, particles):
    if particles.C is not None:
        particles = particles.with_(C=np.zeros_like(particles.C))
    return make_backend("numpy", scene).p2g(particles)


def solve():
    report = check({"p2g": p2g_without_affine_term}, make_cases(dims=(2,), stages=("p2g",)))
    failed = report.failures()
    assert failed and report.failed_stages() == {"p2g"}
    for result in report.results:
        scheme = result.case.scene_dict["method"].get("scheme", "mls")
        assert result.passed == (scheme not in AFFINE), (result.case.variant, result.errors)
    assert {r.worst_output for r in failed} == {"grid_momentum"}
    assert all(r.errors["grid_mass"] == 0.0 and r.errors["grid_force"] == 0.0 for r in failed)
    return {"cases": len(report.results), "failed": sorted(r.case.variant for r in failed)}


if __name__ == "__main__":
    print(solve())
