r"""Synchronous against asynchronous (regional) time stepping (Fang, Hu, Hu & Jiang, SCA 2018).

Parts (the one-level comparison on both backends; the 2D pairs and the sweeps over steps on Numba, as they
compare stepping schemes, not backends, and time their runs; the rest on the backend the case is run with):

* **one level**: ``time.levels = 0`` forces every block to one tick; the asynchronous run must be the
  synchronous run at Δt = one tick, bit for bit (particle order is kept), after ``one_level_steps`` steps;
* **free fall**: a stiff and a soft body on different levels, gravity, no walls. Partition of unity makes a
  uniform velocity field exact in P2G and G2P whatever the ghosts, so the centre-of-mass velocity is
  :math:`v_0 + g t` at every synchronised time to round-off;
* **schedule**: the two-block worked example of Fang et al. (F at 1 tick, C at 2) reproduced update by
  update, and an id census over ``census_ticks`` ticks of random level changes;
* **balls**: two elastic balls of very different stiffness (E ratio ``ball_E_ratio``), no gravity, collide;
  synchronous stepping at the finest asynchronous step against asynchronous stepping, compared at every
  synchronised time: total energy, positions (matched by particle id) in units of Δx, linear and angular
  momentum drift of each — the error at level interfaces is measured, not assumed zero;
* **stork** (2D and 3D): the stiff/soft scene of ``examples/stork2d.toml`` / ``stork3d.toml``: particle
  updates (ghosts included) and wall time of both runs, energy and position difference;
* **isolated**: a soft and a stiff disk pressed together and spinning, in free space (no gravity, no wall
  reached): nothing external acts, so total linear and angular momentum must stay constant;
* **ledger**: the same disks with the energy ledger (:class:`mpmref.observe.ledger.LevelLedger`): at every synchronised
  time the change it books (each level update's active particles, and the registers) must be the change of total
  energy the diagnostics measure; how much of it crosses the level interfaces is a finding;
* **both interface treatments** (``time.interface``, :mod:`mpmref.physics.interface`) side by side in the
  paired runs: ``conservative`` (impulse refluxing) and ``reference`` (Fang et al. 2018 as published);
* **bonded at every CFL number**: the 2D stork at several CFL numbers, energy against sync;
* **balls over ticks**: the colliding balls at shrinking steps (the level ratio fixed), the end state of
  each treatment against sync at its finest step and at a 4x finer one, with fitted slopes;
* **trade**: error against wall time on the 2D stork for sync at several steps and async at several CFL
  numbers and level counts, against a reference sync run at a 4x finer step; the Pareto front marked.

Bounds: bit equality for one level; :math:`10^{-12}` relative for free fall (a few hundred steps of
round-off); energy within 2 % of the synchronous curve and final positions within 0.5 Δx (targets set
from the AsyncMPM reference's reported agreement); at least 3× fewer particle updates on the
2D stork (the talk reports 3.3× on its stork). No particle may be lost: the census raises otherwise.
With conservative interfaces, linear momentum (and angular momentum for MLS-MPM) is conserved to
:math:`10^{-12}` of :math:`\sum_p m_p |v_p|` on the isolated scene and on the balls (round-off of a few
hundred level updates), the ledger's booked energy change is the measured one to :math:`10^{-12}` of the
initial energy at every synchronised time, and bonded bodies stay within 1 % of sync in energy at every CFL number
(the target set for the conservative treatment). The reference treatment's drift is a finding. The balls' end-state
difference is a finding too, not a check: synchronous MPM on contact does not converge as Δt shrinks (its transfers
dissipate per step, measured in the case), so no rate against it can be derived.

On a backend that implements a part (:mod:`verification.framework.applicable`): the claims compare asynchronous with
synchronous stepping on these solids, so the case runs only on a backend that implements every scene it runs on it
(:func:`scenes_on_backend`) as declared, and is not applicable, with the reasons, to any other.

The case is a package: :mod:`.scenes` (its parameters and scenes), :mod:`.levels` (one level, free fall, the schedule
and its steppers), :mod:`.pairs` (the paired runs and their comparison), :mod:`.conservation` (the isolated disks'
momentum and energy ledger), :mod:`.sweeps` (the sweeps: bonded, balls over steps, error against wall time) and
:mod:`.reporting` (checks, findings, figures and tables).
"""

from mpmref.backends import BACKENDS
from mpmref.scene.factories import example_with_time
from mpmref.steppers import AsynchronousStepper

from ..framework.applicable import NothingApplicable, require
from ..framework.case import VerificationCase
from .conservation import isolated, ledger_split
from .levels import ONE_LEVEL_BLOCK, ONE_LEVEL_TICK, WORKED_EXAMPLE, FrozenShadows, free_fall, one_level, schedule
from .pairs import ball_pair, compare, stork_pair
from .reporting import PAIRS, ROUND_OFF, backends_run, checks, findings, report
from .scenes import Params, census_scene, pressed_disks, two_bodies
from .sweeps import ball_series, bonded_at_cfls, trade

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "trade.png"


def scenes_on_backend(params):
    """``[(name, scene)]`` that the case runs on the backend it is asked for: the two bodies (the one-level comparison,
    free fall, the schedule), the pressed disks (isolated, ledger) and the 3D stork."""
    return [("the two bodies (one level, free fall, schedule)", two_bodies(cfl=0.5, tick=ONE_LEVEL_TICK, levels=0,
                                                                           steps=1, block=ONE_LEVEL_BLOCK)),
            ("the pressed disks (isolated, ledger)", pressed_disks()),
            ("the 3D stork", example_with_time("stork3d", params.stork3d_t_end, cells=params.stork3d_cells))]


def compiled_scenes(params, backend="numpy"):
    """``[(backend, scene)]`` whose kernels this case needs compiled (see :mod:`verification.framework.warmup`), on
    Numba whatever ``backend`` is: the one-level comparison's two scenes and the census. Their kernels serve the 2D
    pairs and sweeps too, and their asynchronous bookkeeping (compiled with them) every asynchronous run of the
    case: it depends only on which particle fields a scene allocates. None when the case is not applicable to
    ``backend``."""
    try:
        require(backend, scenes_on_backend(params))
    except NothingApplicable:
        return []
    return [("numba", two_bodies(cfl=0.5, tick=ONE_LEVEL_TICK, levels=0, steps=1, block=ONE_LEVEL_BLOCK)),
            ("numba", two_bodies(stepping="sync", dt=ONE_LEVEL_TICK, steps=1, block=ONE_LEVEL_BLOCK)),
            ("numba", census_scene())]


def run(params=Params(), backend="numpy", executor=None):
    """Every part of the case (see the module docstring), in this process (``executor`` is not used);
    :class:`~verification.framework.applicable.NothingApplicable` for a backend that does not implement its scenes."""
    require(backend, scenes_on_backend(params))
    out = {"params": params, "backend": backend}
    out["one_level"] = [one_level(params, b) for b in ("numpy", "numba")]
    out["free_fall"] = free_fall(params, backend)
    out["schedule"] = schedule(params, backend)
    out["isolated"] = {itf: isolated(params, backend, itf) for itf in params.interfaces}
    out["ledger"] = {itf: ledger_split(params, backend, itf) for itf in params.interfaces}
    # the 2D pairs and the sweeps over steps compare stepping schemes, not backends: they run compiled (the
    # trade's wall times are its cost axis, and the NumPy reference would take minutes); the 3D stork runs on
    # the requested backend
    sweeps = "numba" if "numba" in BACKENDS else backend
    for itf in params.interfaces:
        out[f"balls/{itf}"] = ball_pair(params, sweeps, itf)
        out[f"stork2d/{itf}"] = stork_pair("stork2d", params.stork_t_end, sweeps, params.frames, interface=itf)
        out[f"stork3d/{itf}"] = stork_pair("stork3d", params.stork3d_t_end, backend, params.frames,
                                           cells=params.stork3d_cells, interface=itf)
        for key in ("balls", "stork2d", "stork3d"):
            out[f"{key}/{itf}"]["compare"] = compare(out[f"{key}/{itf}"])
    out["bonded"] = bonded_at_cfls(params, sweeps)
    out["series"] = ball_series(params, sweeps)
    out["trade"] = trade(params, sweeps)
    out["sweeps_backend"] = sweeps
    return out


#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings, backends_run=backends_run,
                        compiled_scenes=compiled_scenes, main_figure=MAIN_FIGURE)

__all__ = ["CASE", "MAIN_FIGURE", "ONE_LEVEL_BLOCK", "ONE_LEVEL_TICK", "PAIRS", "ROUND_OFF", "WORKED_EXAMPLE",
           "AsynchronousStepper", "FrozenShadows", "Params", "backends_run", "ball_pair", "ball_series",
           "bonded_at_cfls", "census_scene", "checks", "compare", "compiled_scenes", "findings", "free_fall",
           "isolated", "ledger_split", "one_level", "pressed_disks", "report", "run", "schedule", "stork_pair",
           "trade", "two_bodies"]
