r"""Exercise 11: find the energy leak with the ledger.

Task. ``exercises.leaky_backend.LeakyBackend`` runs the energy case's oscillating jelly (MLS-MPM) and loses energy
faster than the reference. One of its stages leaks. Without reading its code, find which stage, and how many joules
it loses in one step, with the energy ledger (``docs/energy_ledger.md``): book the same step from the same state
on both backends and compare the terms. Then predict what the leaking stage does to the particles, from the size
of the leak.

Prediction. Each term belongs to one stage, so only the leaking stage's term moves; a stage that runs after it
sees the same inputs within this one step. Suppose the leak is in G2P, and G2P keeps :math:`k\,C_p` instead of the
affine matrix :math:`C_p` (the deformation gradient updated with the right one). The particles' affine kinetic
energy :math:`K_{aff} = \tfrac12 \sum_p m_p D \|C_p\|^2` (``docs/energy_ledger.md``, P2G) becomes
:math:`k^2 K_{aff}`, so ``g2p_transfer`` falls by :math:`(1 - k^2) K_{aff}` exactly, and ``energy_change`` with
it; P2G, the grid update and the return map book what the reference books, and so does ``integration``, since
the deformation gradient is right. Measure the drop, divide it by :math:`K_{aff}` of the honest step, and
:math:`k = \sqrt{1 - \text{ratio}}`. Over a run the leak compounds: every step drops a share of the affine energy.

Worked solution. From a state 20 steps into the reference run, :func:`mpmref.conformance.stages.ledger_step` books
one step on each backend; the term with the largest difference is ``g2p_transfer``, its drop is 0.75 of
:math:`K_{aff}` to 1e-9, so :math:`|k| = 1/2`, and every term of the other stages agrees to round-off of the energy
scale. The conformance harness's ledger stage (``docs/conformance.md``) says the same on its random states: the
affine schemes' ledger cases fail, on ``ledger_g2p_transfer``.
"""

import numpy as np

from exercises.leaky_backend import LeakyBackend
from mpmref.backends import make_backend
from mpmref.conformance import check, make_cases
from mpmref.conformance.stages import ledger_step
from mpmref.observe.diagnostics import kinetic_parts
from mpmref.observe.ledger import COLUMNS
from mpmref.steppers import substep
from verification import energy
from verification.momentum import VARIANT

#: the terms of the stages that run before G2P or do not see C_p in this step
OTHER_STAGES = ("p2g_transfer", "boundary", "advection", "plastic", "rigid_bodies", "integration", "internal_work",
                "gravity_work")


def solve():
    sim = energy.make_simulation(energy.Params.quick(), "jelly", VARIANT["mls"])
    sim.run(steps=20)
    scene, particles, dt = sim.scene, sim.particles, sim.stepper.time_step(sim.particles)
    honest, leaky = (ledger_step(backend, particles, dt, sim.time) for backend in (sim.backend, LeakyBackend(scene)))
    differences = {c: leaky[f"ledger_{c}"] - honest[f"ledger_{c}"] for c in COLUMNS}
    assert max(differences, key=lambda c: abs(differences[c])) in ("g2p_transfer", "energy_change")
    after = substep(make_backend("numpy", scene), particles, dt, sim.time)
    affine = kinetic_parts(after, sim.inertia)[1]
    ratio = -differences["g2p_transfer"] / affine
    assert abs(ratio - 0.75) < 1e-9 and abs(differences["energy_change"] - differences["g2p_transfer"]) < 1e-12 * affine
    assert all(abs(differences[c]) <= 1e-12 * honest["energy_scale"] for c in OTHER_STAGES)
    report = check(LeakyBackend, make_cases(dims=(2,), stages=("ledger",)))
    failed = report.failures()
    assert {r.case.name for r in failed} == {r.case.name for r in report.results if r.case.scene().transfer.affine}
    assert {r.worst_output for r in failed} <= {"ledger_g2p_transfer", "ledger_energy_change"}
    return {"g2p_transfer_drop": -differences["g2p_transfer"], "affine_energy": affine, "ratio": ratio,
            "k": float(np.sqrt(1.0 - ratio)), "failed_ledger_cases": len(failed)}


if __name__ == "__main__":
    print(solve())
