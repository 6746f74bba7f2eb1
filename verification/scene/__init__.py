"""``mpmref verify --scene SCENE.toml --backend B``: the user's own scene turned into the checks that apply to it.

Four checks, each a :class:`~verification.framework.case.VerificationCase` run on the backend ``B`` (a folder of the
report each):

* :mod:`.momentum` (``momentum``): the scene's bodies and materials with gravity, walls, colliders, rigid bodies and
  emitters removed, set drifting and spinning rigidly, on a domain padded so that nothing leaves it: linear momentum
  for every scheme and angular momentum for APIC, MLS-MPM and PolyPIC conserved to round-off, PIC's and FLIP's loss
  of a rigid spin measured against its prediction (the bounds of :mod:`verification.momentum`);
* :mod:`.ledger` (``energy_ledger``): the scene as declared with the energy ledger on: the terms add up to the
  change of total energy, and the signs theory fixes for the scene hold (:mod:`verification.energy_ledger`);
* :mod:`.reference` (``reference``): the backend against the NumPy reference from the scene's own particles, step
  by step, within :math:`n \\cdot 10^{-12}` in float64 and :math:`n` times the conformance tolerance in float32
  (:mod:`verification.backends`); with ``--backend numpy``, the Numba backend is the candidate, as in that case;
* :mod:`.stability` (``stability``): the scene at CFL 0.3, at its scheme's measured limit and at twice its kernel's
  linear limit: bounded at the first, caught at the third (:mod:`verification.extremes`).

Every run is the scene's own run, shortened: at most ``max_steps`` steps and ``budget`` particle-steps (``--quick``,
the default and ``--full``: :data:`PRESETS`), at least ``min_steps``; each report says what ran. An asynchronous
scene runs synchronously at its CFL number (its asynchronous stepping is the ``sync_vs_async`` case's). A part that
the backend cannot do on the scene is *not applicable*, with the reasons (:mod:`verification.framework.applicable`).
"""

import copy
import importlib
from dataclasses import dataclass
from pathlib import Path

from mpmref import Scene
from mpmref.io.atomic import write_text_atomic
from mpmref.scene.parsers import ASYNC_TIME_KEYS

from ..framework.common import checks_table
from ..framework.report import pyplot, save_figure

#: check name -> module, in the order they run
CHECKS = {"momentum": "verification.scene.momentum", "energy_ledger": "verification.scene.ledger",
          "reference": "verification.scene.reference", "stability": "verification.scene.stability"}

#: per preset: the particle-steps a run may take and its most steps (fewer for a large scene, never under min_steps)
PRESETS = {"quick": {"budget": 400_000, "max_steps": 50}, "default": {"budget": 4_000_000, "max_steps": 200},
           "full": {"budget": 40_000_000, "max_steps": 1000}}


@dataclass(frozen=True)
class Params:
    """What a ``--scene`` check runs: the scene file, and how long its runs may be.

    ``budget``: particle-steps of one run; ``max_steps`` and ``min_steps``: its length whatever the budget.
    """

    scene: str = ""
    budget: int = PRESETS["default"]["budget"]
    max_steps: int = PRESETS["default"]["max_steps"]
    min_steps: int = 10

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
        """The steps of a run of ``n_particles`` particles: within the budget, between ``min_steps`` and
        ``max_steps``."""
        return max(self.min_steps, min(self.max_steps, self.budget // max(1, n_particles)))


def load(params):
    """The user's scene, validated (:class:`~mpmref.errors.SceneError` otherwise)."""
    return Scene.from_toml(Path(params.scene))


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


def what_ran(scene, steps, dt_text):
    """One sentence for a report: which scene ran, how many steps, and how that compares with the scene's own run."""
    own = scene.time.steps if scene.time.steps is not None else None
    length = f" of the scene's {own}" if own else ""
    stepping = " synchronously (the scene steps asynchronously)" if scene.time.stepping == "async" else ""
    return (f"Scene '{scene.name}' ({scene.dim}D, {scene.method.scheme}), {steps} steps{length}{stepping}, "
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


def write_report(out_dir, name, title, result, checks, figure, table=""):
    """Write a check's ``NAME.png`` (``figure(result, path)``) and ``NAME.md``: ``title``, what ran, ``table``, the
    checks and the figure; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    png = figure(result, out / f"{name}.png")
    table = f"{table}\n\n" if table else ""
    write_text_atomic(out / f"{name}.md", f"# {title}\n\n{result['ran']}\n\n{table}{checks_table(checks)}\n\n"
                      f"![{name}]({name}.png)\n")
    return [png, out / f"{name}.md"]
