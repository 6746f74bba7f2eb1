r"""Exercise 10: the order of the vibrating bar's error with ``mpmref study``, for APIC and for PIC.

Prediction. The convergence chapter (``docs/convergence.md``) derives the orders: APIC with the classic force
and the quadratic B-spline is second order in :math:`\Delta x` at a fixed CFL number (a consistent
second-order transfer, force and time integration), and PIC is first order, because its transfer pair damps a
resolved mode by :math:`\sigma^2 (k\Delta x)^2` per step over :math:`O(1/\Delta x)` steps
(:func:`verification.convergence.pic_bound_constant`). So the displacement error :math:`e_u` at :math:`T/4`
falls as :math:`\Delta x^2` and :math:`\Delta x`, and Richardson's estimate from the three levels agrees.

Measurement. A study needs three things the scene file cannot declare, and this module gives them as functions
(on the command line: ``--setup``, ``--measure``, ``--exact``):

* the bar's mode shape as initial velocity, :func:`setup`: the half-step start
  :math:`v_p = v(X_p, -\Delta t/2)`, :math:`C_p = \nabla v(X_p, -\Delta t/2)` of the convergence case
  (:func:`verification.convergence.initial_particles`);
* the error itself as a measure, :func:`displacement_error` (the case's relative RMS errors
  :func:`verification.convergence.errors`);
* its exact value, zero (:func:`exact`), so that orders are measured against it.

The fixed end of the bar is a symmetry plane, which no wall expresses; the scene (:func:`bar_scene`) is the bar
doubled by reflection, :math:`[-L, L]`, free at both ends, which is the mirror treatment exactly
(``tests/test_verify_convergence.py`` checks it). Space and time are refined together with the case's uniform
steps (``grid.cells:time.dt`` linked), so each level is the convergence case's run. The measured orders are
compared with the predictions within the convergence case's own rate tolerance, 0.3.
"""

import math

from mpmref.scene.sampling import sample_particles
from verification import convergence as case
from verification.convergence.problems import VibratingBar
from verification.framework.executor import Executor
from verification.study import run_study

BAR = VibratingBar()
#: the levels of the convergence case's quick preset: cells along the bar
BAR_CELLS = (16, 32, 64)
#: cells of the doubled bar's grid beyond each free end (at the coarsest level), and its height in cells
ROOM, HEIGHT = 3, 4


def bar_scene(scheme="apic"):
    """The doubled bar as scene declarations: ``[-L, L]`` times one coarse cell, open walls, coarsest grid."""
    dx = BAR.length / BAR_CELLS[0]
    half = BAR.length + ROOM * dx
    return {"name": "doubled_bar", "dim": 2,
            "grid": {"size": [2 * half, HEIGHT * dx], "cells": round(2 * half / dx), "origin": [-half, -2 * dx]},
            "method": {"scheme": scheme, "force": "classic", "kernel": "quadratic"},
            "materials": {"bar": {"type": "fixed_corotated", "E": BAR.E, "nu": 0.0, "rho": BAR.rho}},
            "bodies": [{"shape": "box", "material": "bar", "lower": [-BAR.length, 0.0], "upper": [BAR.length, dx],
                        "ppc": 4}],
            "boundary": {"type": "open", "width": 0}, "time": {"dt": 1.0}}


def levels():
    """``(grid cells, Δt)`` per level: the doubled grid's cells and the convergence case's step on that level."""
    width = bar_scene()["grid"]["size"][0]
    return [(round(width * cells / BAR.length),
             case.time_step(BAR, BAR.scene(cells, {"scheme": "apic"}, 2), case.CFL)[0])
            for cells in BAR_CELLS]


def setup(sim):
    """The bar's first mode at the half step before t = 0 (velocity and, for the affine schemes, C)."""
    sim.particles = case.initial_particles(BAR, sim.particles, sim.scene.time.dt)


def displacement_error(sim):
    """The convergence case's relative RMS displacement and velocity errors of the finished run."""
    X = sample_particles(sim.scene).x[sim.id]
    e_u, e_v = case.errors(BAR, sim.particles, X, sim.time, sim.scene.time.dt)
    return {"displacement_error": e_u, "velocity_error": e_v}


def exact(scene, t):
    """The errors' exact value: zero."""
    return {"displacement_error": 0.0, "velocity_error": 0.0}


def study(scheme, out, executor=None):
    """The study of the doubled bar under ``scheme`` on the three levels, written into ``out``."""
    return run_study(bar_scene(scheme), {("grid.cells", "time.dt"): levels()}, t_end=BAR.end_time(), out=out,
                     measures=[displacement_error], exact=exact, setup=setup, ledger=False,
                     executor=executor or Executor(workers=1))


def order_of(result, measure="displacement_error"):
    """The fitted order and Richardson's estimate of ``measure`` in a study's orders."""
    row = next(r for r in result["orders"] if r["measure"] == measure)
    return row["order"], row["richardson"]


def solve():
    import tempfile

    found = {}
    with tempfile.TemporaryDirectory() as folder:
        for scheme, predicted in (("apic", 2.0), ("pic", 1.0)):
            fitted, richardson = order_of(study(scheme, f"{folder}/{scheme}"))
            assert abs(fitted - predicted) <= 0.3, f"{scheme}: fitted order {fitted:.3f}, predicted {predicted}"
            assert abs(richardson - predicted) <= 0.3, f"{scheme}: Richardson {richardson:.3f}, predicted {predicted}"
            found.update({f"{scheme}_fitted": fitted, f"{scheme}_richardson": richardson})
    assert not math.isnan(sum(found.values()))
    return found


if __name__ == "__main__":
    print(solve())
