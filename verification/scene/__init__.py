r"""``mpmref verify --scene SCENE.toml --backend B``: the user's own scene turned into the checks that apply to it.

The scene's own run, on the backend ``B``, is advanced over a span of it (:func:`trajectory`: a fraction of its steps
set by the preset, within a budget of particle-steps), and its state kept at ``starts`` steps evenly spread over the
span: the first at the start, the last near the end, where the scene has done most of what it does (a body that falls
at first has landed). Four checks, each a :class:`~verification.framework.case.VerificationCase` (a folder of the
report each):

* :mod:`.momentum` (``momentum``): the scene's bodies and materials with gravity, walls, colliders, rigid bodies and
  emitters removed, set drifting and spinning rigidly, on a domain padded so that nothing leaves it: linear momentum
  for every scheme and angular momentum for APIC, MLS-MPM and PolyPIC conserved to round-off, PIC's and FLIP's loss
  of a rigid spin measured against its prediction (the bounds of :mod:`verification.momentum`);
* :mod:`.ledger` (``energy_ledger``): the scene as declared with the energy ledger on, from the last kept state: the
  terms add up to the change of total energy, and the signs theory fixes for the scene hold
  (:mod:`verification.energy_ledger`);
* :mod:`.reference` (``reference``): from each kept state, the backend and the NumPy reference step the same
  particles for ``segment`` steps, within :math:`n \cdot 10^{-12}` in float64 and :math:`n` times the conformance
  tolerance in float32 (:mod:`verification.backends`); with ``--backend numpy``, the Numba backend is the candidate,
  as in that case;
* :mod:`.stability` (``stability``): from the last kept state, the scene at CFL 0.3, at its scheme's measured limit and
  at twice its kernel's linear limit: bounded at the first, caught at the third (:mod:`verification.extremes`).

The checks' own runs are at most ``max_steps`` steps and ``budget`` particle-steps, at least ``min_steps``
(:data:`PRESETS`: ``--quick``, the default, ``--full``); each report says what ran. An asynchronous scene runs
synchronously at its CFL number (its asynchronous stepping is the ``sync_vs_async`` case's). A part the backend
cannot do on the scene is *not applicable*, with the reasons (:mod:`verification.framework.applicable`).
"""

import copy
import importlib
import math
import warnings
from collections import deque
from dataclasses import dataclass, fields, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from mpmref import Scene, Simulation
from mpmref.errors import MpmrefError
from mpmref.run.emitters import schedule
from mpmref.run.stability import StabilityWarning
from mpmref.scene.parsers import ASYNC_TIME_KEYS

from ..framework.page import Checks, Figure, Page, Text, write_page
from ..framework.report import pyplot, save_figure

#: check name -> module, in the order they run
CHECKS = {"momentum": "verification.scene.momentum", "energy_ledger": "verification.scene.ledger",
          "reference": "verification.scene.reference", "stability": "verification.scene.stability"}

#: per preset: the particle-steps (``budget``) and most steps of a check's run; the fraction of the scene's own run
#: advanced (``span``) within ``advance`` particle-steps; the kept states (``starts``) and the steps compared from each
#: (``segment``)
PRESETS = {"quick": {"budget": 400_000, "max_steps": 50, "span": 1 / 3, "advance": 10_000_000, "starts": 3,
                     "segment": 5},
           "default": {"budget": 4_000_000, "max_steps": 200, "span": 1.0, "advance": 100_000_000, "starts": 6,
                       "segment": 20},
           "full": {"budget": 40_000_000, "max_steps": 1000, "span": 1.0, "advance": 10**12, "starts": 12,
                    "segment": 50}}


@dataclass(frozen=True)
class Params:
    """What a ``--scene`` check runs: the scene file, and how long its runs may be (:data:`PRESETS`)."""

    scene: str = ""
    budget: int = PRESETS["default"]["budget"]
    max_steps: int = PRESETS["default"]["max_steps"]
    min_steps: int = 10
    span: float = PRESETS["default"]["span"]
    advance: int = PRESETS["default"]["advance"]
    starts: int = PRESETS["default"]["starts"]
    segment: int = PRESETS["default"]["segment"]

    @classmethod
    def quick(cls):
        return cls(**PRESETS["quick"])

    @classmethod
    def full(cls):
        return cls(**PRESETS["full"])

    @classmethod
    def of(cls, scene, preset):
        """The parameters of ``preset`` for the scene file ``scene``."""
        return cls(scene=str(scene), **PRESETS[preset])

    def steps(self, n_particles):
        """The steps of a check's run of ``n_particles`` particles: within the budget, between ``min_steps`` and
        ``max_steps``."""
        return max(self.min_steps, min(self.max_steps, self.budget // max(1, n_particles)))


def load(params):
    """The user's scene, validated (:class:`~mpmref.errors.SceneError` otherwise)."""
    return Scene.from_toml(Path(params.scene))


@dataclass(frozen=True)
class Trajectory:
    """The scene's own run on a backend, advanced over ``span`` of its ``own`` steps: the synchronous ``scene`` and its
    ``states`` (:class:`~mpmref.state.State`) at the steps ``kept``. ``stopped``: ``None``, or how the run stopped
    before the span's end (the engine's error: an instability, a particle out of the domain); the last kept state is
    then ``segment`` steps before the stop (or the first), so that a segment from it reaches the stop."""

    scene: Scene
    own: int
    span: int
    kept: tuple
    states: tuple
    stopped: str | None = None


def trajectory(params, backend):
    """The :class:`Trajectory` of ``params``'s scene on ``backend`` (one run, shared by the checks that start from it):
    ``span`` of the scene's own steps, at most ``advance`` particle-steps, at least ``segment`` + 1; its states at
    ``starts`` steps evenly spread from the first to the last one that leaves ``segment`` steps to the span's end."""
    stat = Path(params.scene).stat()
    return _trajectory(params, backend, (stat.st_mtime_ns, stat.st_size))


@lru_cache(maxsize=4)
def _trajectory(params, backend, version):
    scene = as_run(load(params))
    sim = Simulation(scene, backend=backend)
    own = own_steps(scene, sim)
    span = max(params.segment + 1, min(math.ceil(params.span * own), params.advance // max(1, sim.n_particles)))
    last = span - params.segment
    wanted = {round(k * last / max(1, params.starts - 1)) for k in range(params.starts)}
    states, recent = {}, deque(maxlen=params.segment)
    while True:
        recent.append(snapshot(sim.state))
        if sim.step_count in wanted:
            states[sim.step_count] = recent[-1]
        if sim.step_count >= last:
            break
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", StabilityWarning)  # the checks judge what this run reaches
                sim.step()
        except MpmrefError as exc:  # the last start: a segment before the stop, so its steps reach it
            states[recent[0].step] = recent[0]
            stopped = f"the scene's run on {backend} stopped at step {sim.step_count + 1}: {type(exc).__name__}: {exc}"
            return Trajectory(scene, own, span, tuple(sorted(states)), tuple(states[k] for k in sorted(states)),
                              stopped)
    return Trajectory(scene, own, span, tuple(states), tuple(states.values()))


def own_steps(scene, sim):
    """The steps of the scene's own run: ``time.steps``, or ``time.t_end`` over its fixed step (over its first CFL step:
    an estimate, since the CFL step changes as the particles do)."""
    if scene.time.steps is not None:
        return scene.time.steps
    if scene.time.t_end is None:
        return 0
    return math.ceil(scene.time.t_end / sim.stepper.time_step(sim.particles))


def snapshot(state):
    """A copy of a run's :class:`~mpmref.state.State` that later steps cannot change: its arrays copied (the rigid
    bodies' too; their mechanics, a module, shared)."""
    rigid = state.rigid
    if rigid is not None:
        rigid = replace(rigid, **{f.name: np.array(getattr(rigid, f.name)) for f in fields(rigid) if f.init})
    return replace(state, particles=state.particles.copy(), rigid=rigid, stepper=copy.deepcopy(state.stepper))


def resume(scene, backend, state):
    """A simulation of ``scene`` on ``backend`` from a copy of ``state`` (a state of the same scene's run, whatever
    its outputs: the run's own records start afresh, e.g. the energy ledger's totals and what entered and left at zero;
    the emitters' releases so far are kept, so that it releases what the scene's run releases next, when it does,
    :func:`mpmref.run.emitters.schedule`)."""
    sim = Simulation(scene, backend=backend, particles=state.particles.copy())
    copied = snapshot(state)
    sim.state = replace(copied, stepper={**sim.state.stepper, **schedule(copied)})
    return sim


def matched(before, after):
    """Rows ``(i, j)`` of the particles that two states both hold, by their stable ids ``before`` and ``after``
    (``before[i] == after[j]``): what a comparison of the two compares, whatever entered (emitters), left (deleted at
    the domain's edge) or was reordered in between."""
    _, i, j = np.intersect1d(before, after, assume_unique=True, return_indices=True)
    return i, j


def case(name):
    """The :class:`~verification.framework.case.VerificationCase` of check ``name``."""
    return importlib.import_module(CHECKS[name]).CASE


def as_run(scene, ledger=False, **changes):
    """The declaration of ``scene`` for a check's run: synchronous (an asynchronous scene at its CFL number), no output
    but the energy ledger if asked, and ``changes`` (top-level keys) applied; returns the new :class:`Scene`."""
    data = copy.deepcopy(scene.source)
    time = {k: v for k, v in data.get("time", {}).items() if k not in (*ASYNC_TIME_KEYS, "stepping")}
    data["time"] = time
    data["output"] = {"energy_ledger": True} if ledger else {}
    data.update(changes)
    return Scene.from_dict(data, base_dir=scene.base_dir)


def what_ran(scene, steps, dt_text, start=None):
    """One sentence for a report: which scene ran, how many steps from which step of its own run
    (:class:`Trajectory`), and how its steps were sized."""
    stepping = " synchronously (the scene steps asynchronously)" if scene.time.stepping == "async" else ""
    begin = "" if start is None else (f", from step {start[0]} of its own run (its state there on the backend under "
                                      f"test; the run is {start[1]} steps)")
    return (f"Scene '{scene.name}' ({scene.dim}D, {scene.method.scheme}), {steps} steps{begin}{stepping}, "
            f"{dt_text}.")


def figure_with(draw, path, caption, **axes):
    """A figure of one axes drawn by ``draw(ax)``, labelled with ``axes`` (``ax.set``), gridded, with a legend, saved
    with its ``caption``."""
    fig, ax = pyplot().subplots(figsize=(7, 4.5))
    draw(ax)
    ax.set(**axes)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path, caption=caption)


def write_report(out_dir, name, title, result, checks, figure, table=None):
    """Write a check's ``NAME.png`` (``figure(result, path)``) and ``NAME.md``: ``title``, what ran, ``table`` (a
    :class:`~verification.framework.page.Table`, or ``None``), the checks and the figure; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    png = figure(result, out / f"{name}.png")
    page = Page(title, [Text(result["ran"]), *([table] if table else []), Checks(checks), Figure(f"{name}.png", name)])
    return [png, write_page(page, out / f"{name}.md")]
