r"""CPIC: thin rigid bodies that are not crossed, cut material, exchange momentum both ways and carry friction.

2D scenes and one 3D scene on the NumPy reference (compatible PIC, Hu et al. 2018 §4–5; docs/cpic.md):

* **No crossing.** A jelly block falls under gravity onto a fixed zero-thickness segment and rests on it;
  a scripted blade moves at 1 m/s through a layer of sand. A *crossing* is a particle whose signed offset
  from a segment's line changes sign between two consecutive steps while its projection lies on the
  segment (both times). CPIC's claim is that there are none: a particle exchanges momentum only with nodes
  on its own side, and its side tag is sticky. Bound: 0, over every step of the run.
  The blade's pushing force is set from its speed and the grid (:func:`~.scenes.sand_scene`); the default
  preset also reports the reference's fixed 2e4.
* **Hard impact.** The jelly block hits the segment at 5 m/s. Some particles do cross the line for a few
  steps (reported): nothing on the grid stops them, only the ghost velocities, the pushing force and the
  penalty. Because their side tag is kept, they are seen as having penetrated (negative distance) and are
  pushed back: the check is that no particle is on the far side at the end (bound 0). Recomputing the tags
  every step instead (the broken variant of the tests) lets them join the far side and fails it.
* **Momentum balance.** A free thin plate (dynamic, no gravity, no walls) is hit by a jelly ball at 1 m/s.
  Particles plus plate conserve linear momentum exactly in the momentum-exact variant (PIC, the plate's
  velocity frozen over the step, no pushing force: what a particle keeps at an incompatible node plus what
  the plate receives is its momentum there, and the internal forces sum to zero): bound 1e-12 relative to
  :math:`m_{ball}|v|`. The default variant (the plate's velocity updated between P2G and G2P) is reported,
  not judged. Two-way: the plate must move along the ball's velocity.
* **Cutting.** A jelly block falls onto a static wedge blade (two zero-thickness segments meeting at an
  edge): it must end as 2 connected components (particles linked when closer than one cell), with no
  crossing.
* **Cutting in 3D.** A jelly block falls onto two crossed static blades (zero-thickness open triangle meshes,
  each a wedge of two faces meeting at a sharp top edge, one edge along x, the other along z): it must end
  as 4 connected components, and no particle may cross a blade (a crossing as above, with the projection on
  a triangle both times). NumPy reference unless another backend is asked for; coarse in the quick preset.
* **Friction.** A block slides at 1 m/s on a fixed segment with Coulomb friction :math:`\mu` under gravity
  :math:`g`; a block decelerating at :math:`\mu g` stops after :math:`v^2/(2\mu g)`. Bound: within 15 %.
* **Rotor** (default and full presets; reported, not judged). A thin plate spins at 10 rad/s inside a jelly
  block: particles it sweeps are pushed only through the ghost velocities, the pushing force and the penalty,
  and some cross the plate's line for a few steps (by a fraction of a cell); the crossings and the particles
  on the far side at the end are reported.
* **Sand wheel** (Hu et al. 2018's 2D scene, coarser; :func:`~.scenes.wheel_scene`). Sand poured onto a pinned wheel
  (a closed ring of zero-thickness segments with slanted blades welded to it) turns it. Check: over the last
  half of the run the angular velocity keeps the sign it ends with and stays above :func:`~.scenes.wheel_omega_floor`
  (a tenth of the rate at which the sand stream's momentum would balance the wheel's damping). The scene uses
  the per-body fit (``method.cpic_fit = "per_body"``). Check: no sand particle gets deeper inside the ring than
  the penalty window's far edge, 0.3 Δx (within it its kept tag and the penalty bring it back; beyond it, it has
  passed through). The sand found inside the ring by any margin (the acceptance asks for none) is an open
  finding: resting sand creeps a fraction of a cell past the ring's line (docs/cpic.md, "The sand wheel").
  Plot: ω(t).
* **Baselines** (default and full presets; reported, not judged). The same jelly block falls onto a vertical
  cut line at x = 0.5: a CPIC blade (one zero-thickness segment), a level-set collider blade (a box half a
  cell thick, the thinnest a grid resolves), and no blade but the particles within 1 or 1.5 cells of the
  line removed, or softened (shear modulus 0) within 2 cells, as the talk's baselines. For each: particles
  that cross the line (below the blade's top), and mass lost.

On a backend that implements a part (:mod:`verification.framework.applicable`): the claims are CPIC's on these
materials and walls, so the case runs only on a backend that implements every scene it runs (:func:`scenes_on_backend`)
as declared, and is not applicable, with the reasons, to any other.

The case is a package: :mod:`.scenes` (its parameters and scene builders), :mod:`.measurements` (the simulations
and what each measures, :func:`~verification.cpic.measurements.run`), :mod:`.results` (the records they return) and
:mod:`.reporting` (checks, findings, figures and tables).
"""

from ..framework.applicable import require
from ..framework.case import VerificationCase
from .measurements import components, parts, run_part
from .measurements import run as run_parts
from .reporting import backends_run, checks, findings, report
from .scenes import (
    Params,
    ball_scene,
    cut3d_scene,
    cut_scene,
    drop_scene,
    friction_scene,
    impact_scene,
    sand_scene,
    wheel_scene,
)


def scenes_on_backend(params):
    """``[(name, scene)]``: a scene of each kind the case runs on the backend (the examples of its parts)."""
    return [(f"the scene '{scene.name}'", scene) for scene in
            (drop_scene(params), impact_scene(params), sand_scene(params), ball_scene(params, exact=True),
             cut_scene(params), cut3d_scene(params), friction_scene(params), wheel_scene(params))]


def run(params=Params(), backend="numpy", executor=None):
    """:func:`.measurements.run` on a backend that implements every scene of the case
    (:class:`~verification.framework.applicable.NothingApplicable` otherwise)."""
    require(backend, scenes_on_backend(params))
    return run_parts(params, backend, executor)

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "momentum.png"

#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings, backends_run=backends_run,
                        main_figure=MAIN_FIGURE)

__all__ = ["CASE", "MAIN_FIGURE", "Params", "backends_run", "checks", "components", "findings", "parts", "report",
           "run", "run_part", "scenes_on_backend"]
