r"""The energy ledger of the user's scene: its terms add up to the change of total energy, and keep their signs.

The scene as declared (synchronously), with the energy ledger on (``[output] energy_ledger``), run on the backend for
the budget's steps from the last state kept along its own run (:func:`verification.scene.trajectory`: where the scene
has done most of what it does; :func:`verification.energy_ledger.runs.ledger_run`). The checks are those of each run
of the energy-ledger case (:func:`verification.energy_ledger.reporting.run_checks`; docs/energy_ledger.md):

* **closure**: the cumulative terms add up to the change of total energy the diagnostics measure, to
  :math:`(n + 2)\cdot 10^{-12} S` after :math:`n` steps (:math:`S` the run's energy scale);
* **the signs theory fixes for the scene**: the transfers never add energy for PIC, APIC, MLS-MPM and PolyPIC
  without rigid bodies, PolyPIC's G2P keeps everything, static walls and colliders never add energy, a plastic return
  map never does; each to :math:`10^{-12} S` a step.

The bounds are those of float64 arithmetic: in a float32 scene the checks are not applicable. What enters the run
(emitters) and what leaves it (deleted at the domain's edge) the run books as the ledger's ``inflow`` and ``outflow``
(:func:`mpmref.observe.ledger.book_exchange`), checked with the rest; a particle clamped back inside at the edge is
moved by no stage and booked by no term, so when particles are clamped over the run the checks are not applicable
(the report says how many).
"""

from mpmref.observe.ledger import ASYNC_COLUMNS

from ..energy_ledger.reporting import run_checks
from ..energy_ledger.runs import ledger_run, terms_of, total_energy
from ..framework.applicable import NotApplicable
from ..framework.case import VerificationCase
from ..framework.report import ledger_figure
from . import Params, as_run, resume, trajectory, what_ran, write_report
from .momentum import step_text

FRAMES = 10


def run(params, backend="numpy", executor=None):
    """The scene with its ledger on the backend, from the last kept state of its run
    (:func:`~verification.scene.trajectory`), for the budget's steps (``executor`` is not used: one run)."""
    path = trajectory(params, backend)
    ledgered = as_run(path.scene, ledger=True)
    sim = resume(ledgered, backend, path.states[-1])
    start, clamped = sim.step_count, sim.clamped
    r = ledger_run(sim, ledgered.name, FRAMES, steps=params.steps(sim.n_particles))
    why = []
    if ledgered.dtype.name != "float64":
        why.append(f"the bounds are float64 round-off (10^-12 of S); this scene is {ledgered.dtype.name}")
    if sim.clamped > clamped:
        why.append(f"{sim.clamped - clamped} particles were clamped back inside at the domain's edge, which moves them "
                   "outside every stage: the ledger does not book it")
    items = [NotApplicable(f"{ledgered.name}: the ledger's closure and signs", tuple(why))] if why else []
    return {"params": params, "backend": backend, "run": r, "checked": not why, "not_applicable": items,
            "ran": what_ran(ledgered, r["steps"], step_text(ledgered), (start, path.own))}


def checks(result):
    """The run's closure and the signs theory fixes for the scene (none when not applicable)."""
    return run_checks(result["run"]) if result["checked"] else []


def plot(result, path):
    """The stacked cumulative terms of the run, with the change of total energy."""
    r = result["run"]
    energy, change = total_energy(r), r["ledger"][:, ASYNC_COLUMNS.index("energy_change")]
    return ledger_figure([(f"{r['key']} ({r['method']})", r["t"], terms_of(r), change,
                           (r["t"][r["sampled_steps"]], energy - energy[0]))], path, "cumulative energy [J]", caption=(
        f"{r['key']}: where its energy went, the ledger's cumulative terms stacked above zero (energy a stage added) "
        "and below (energy it took), with the change of total energy in black (their sum) and the diagnostics' own "
        "measurement of it as dots. Look for the dots on the line (closure, checked) and the transfers, walls and "
        "plasticity below zero where theory fixes their sign (checked)."))


def report(result, out_dir):
    """Write the stacked terms and ``energy_ledger.md``."""
    return write_report(out_dir, "energy_ledger", f"The energy ledger of {result['run']['key']}", result,
                        checks(result), plot)


#: this check, for ``mpmref verify --scene``
CASE = VerificationCase(__doc__, Params, run, checks, report)
