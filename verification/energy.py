r"""Energy budget: colliding elastic disks (Sulsky et al. 1994) and an oscillating jelly, for every scheme.

Set-ups (no gravity, open walls, CFL time step):

* **disks**: ``examples/colliding_disks.toml`` — two Neo-Hookean disks of radius 0.2 approach at
  :math:`\pm(0.1, 0.1)`, collide, and bounce apart (Sulsky, Chen & Schreyer 1994), on a grid of
  spacing ``disk_dx``. ``disk_head_start`` skips that much free flight by starting each disk
  :math:`v\,t_0` further along; a uniform translation of an unstressed body is reproduced by every
  transfer (partition of unity), so only the approach is shortened;
* **jelly**: a fixed-corotated square block released from a uniform isochoric stretch
  :math:`F_0 = \operatorname{diag}(1+s, 1/(1+s))` at rest; it oscillates, exchanging elastic and kinetic
  energy.

Per scheme, kinetic (particle, affine and PolyPIC-mode parts, :mod:`mpmref.observe.diagnostics`), elastic and total
energy :math:`E` are recorded every step; the budget is :math:`E_0`, :math:`E_{end}` and the lost fraction
:math:`1 - E_{end}/E_0`. The energy ledger (:mod:`mpmref.observe.ledger`) books every step, and its cumulative terms say
where the energy went (figures ``energy_ledger_<problem>.png``; the ``energy_ledger`` case checks them).

Theory and bounds
-----------------
* **No gain beyond time-integration error** (every scheme). Symplectic Euler (velocity first, then
  position) conserves a modified energy :math:`\tilde H = H - \tfrac{\Delta t}{2} H_p^T H_q + O(\Delta t^2)`
  (Hairer, Lubich & Wanner, *Geometric Numerical Integration*, 2nd ed. 2006, ch. IX, backward error
  analysis; for a linear oscillator :math:`p^2 + \omega^2 q^2 - \Delta t\,\omega^2 p q` is exactly invariant),
  and :math:`H_p^T H_q = v \cdot \nabla V = \dot V`, the rate of change of the elastic energy. So
  :math:`|H_n - H_0| \le \tfrac{\Delta t}{2}(|\dot V_n| + |\dot V_0|)`: the transfers can only dissipate,
  hence :math:`\max_n (E_n - E_0) / E_0 \le \Delta t_{max} \max_n |\dot V_n| / E_0`
  (:func:`gain_bound`), with :math:`\dot V` measured step by step. The bound is O(Δt).
* **Ordering of dissipation**. PIC averages the velocity field twice per step and keeps no more than the
  grid field: it dissipates most (Jiang et al. 2015 §6), so it loses more than every other scheme.
  FLIP(α) blends :math:`1-\alpha` of PIC into each G2P, so FLIP(0.95) loses more than FLIP(1). PolyPIC's
  full set of modes keeps what APIC's affine field drops (Fu et al. 2017 §5), so MLS-MPM (APIC transfer)
  loses more than PolyPIC. FLIP(1) is lossless *in transfer* (``transfer_energy`` case) but not over a full
  step — positions move with the grid (PIC) velocity while the particle velocity takes the FLIP increment —
  and theory does not order it against APIC: which of the two loses more depends on the problem and the
  resolution (see the budget tables).

On a backend that implements a part (:mod:`verification.framework.applicable`)
---------------------------------------------------------------------------------
Each scheme runs if the backend has it (with the backend's force where the scheme's label does not name one); an
ordering check needs both of its schemes, and is not applicable otherwise. The gain bound holds for any hyperelastic
material (the modified-energy argument needs only a smooth stored energy :math:`V`), any smooth kernel and any
dimension, and it is computed from the run's own :math:`\dot V`, so a body may be of another hyperelastic material the
backend has (the same density and P-wave speed), the kernel may be the backend's quadratic or cubic B-spline (not the
linear hat: its force jumps where a particle crosses a node, which the argument does not cover, and FLIP with it blows
up on the disks, the reference too), a code without 2D runs the 3D slabs of the disks and the jelly
(:func:`mpmref.backends.fitting.lifted`); open walls may be the backend's walls on a domain padded by their band,
which nothing reaches. A fluid stores energy only in
its volume, so the jelly of a fluid starts from the uniform dilation :math:`J_0 = 1 + s` instead of the isochoric
stretch (the same oscillation between stored and kinetic energy, through the volume).
"""

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpmref import Scene, SceneBuilder, Simulation
from mpmref.backends.fitting import SMOOTH_KERNELS
from mpmref.observe.ledger import TERMS

from .framework.applicable import Allow, Triage, fit
from .framework.case import VerificationCase
from .framework.common import Check
from .framework.executor import Executor
from .framework.page import Checks, Figure, Heading, Page, Table, write_page
from .framework.recording import record
from .framework.report import ledger_figure, pyplot, save_figure, write_series
from .momentum import VARIANT, VARIANTS

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "energy_total_disks.png"

DISKS_TOML = Path(__file__).resolve().parent.parent / "examples" / "colliding_disks.toml"
PROBLEMS = ("disks", "jelly")

#: (more dissipative, less dissipative, reason) pairs of variant keys that theory orders
ORDERINGS = (
    *(("pic", v.key, "PIC keeps only the grid field: it dissipates most") for v in VARIANTS if v.key != "pic"),
    ("flip", "flip1", "FLIP(α) blends 1-α of PIC into each G2P"),
    ("mls", "polypic", "PolyPIC's modes keep what APIC's affine field drops"),
)


@dataclass(frozen=True)
class Params:
    problems: tuple = PROBLEMS
    variants: tuple = tuple(v.key for v in VARIANTS)
    cfl: float = 0.4
    disk_dx: float = 0.0125  # the example's grid
    disk_ppc: int = 4
    disk_t_end: float = 4.0  # simulated time after the head start
    disk_head_start: float = 0.0  # seconds of free flight skipped
    jelly_cells: int = 64  # across the unit domain
    jelly_stretch: float = 0.1
    jelly_t_end: float = 0.1  # about four oscillation periods
    jelly_E: float = 1e3
    jelly_nu: float = 0.3
    jelly_rho: float = 1.0
    frames: int = 10  # VTK frames per run

    @classmethod
    def quick(cls):
        return cls(disk_dx=0.025, disk_t_end=1.8, disk_head_start=1.2, jelly_cells=32, jelly_t_end=0.06)

    @classmethod
    def full(cls):
        return cls(disk_dx=0.00625, jelly_cells=128, jelly_t_end=0.2)


# ------------------------------------------------------------------------------------------ theory
def gain_bound(t, elastic, e0):
    r"""First-order bound on the energy gain of symplectic Euler, relative to :math:`E_0`.

    .. math:: \frac{\max_n (E_n - E_0)}{E_0} \le \frac{\Delta t_{max}\,\max_n |\dot V_n|}{E_0},
              \qquad \dot V_n \approx \frac{V_n - V_{n-1}}{t_n - t_{n-1}}

    from the modified energy :math:`\tilde H = H - \tfrac{\Delta t}{2}\dot V` (module docstring).

    Docs: docs/verification.md#energy-colliding-disks-and-an-oscillating-jelly

    Parameters
    ----------
    t : (n+1,) times;  elastic : (n+1,) elastic energy :math:`V`;  e0 : initial total energy
    """
    dt = np.diff(t)
    return float(dt.max() * np.max(np.abs(np.diff(elastic) / dt)) / e0)


# ------------------------------------------------------------------------------------------- runs
def _disks(params, variant, ledger):
    with open(DISKS_TOML, "rb") as fh:
        data = tomllib.load(fh)
    data["grid"]["dx"] = params.disk_dx
    data.setdefault("output", {})["energy_ledger"] = ledger
    data["method"] = {"scheme": variant.scheme, **variant.method}
    data["time"] = {"cfl": params.cfl, "t_end": params.disk_t_end}
    for body in data["bodies"]:
        body["ppc"] = params.disk_ppc
        body["center"] = [c + params.disk_head_start * u for c, u in zip(body["center"], body["velocity"])]
    return Scene.from_dict(data, base_dir=DISKS_TOML.parent)


def _jelly(params, variant, ledger):
    return (SceneBuilder(dim=2, name="jelly_oscillation").grid(size=1.0, cells=params.jelly_cells)
            .method(variant.scheme, **variant.method)
            .material("jelly", "fixed_corotated", E=params.jelly_E, nu=params.jelly_nu, rho=params.jelly_rho)
            .box("jelly", lower=[0.35, 0.35], upper=[0.65, 0.65], ppc=4)
            .walls("open").time(cfl=params.cfl, t_end=params.jelly_t_end).output(energy_ledger=ledger).build())


#: what the claims let a backend that implements a part change (module docstring); a variant that does not name its
#: force lets it change too (:meth:`~verification.momentum.Variant.allows`)
ALLOWS = Allow(materials="substitute", walls="open", kernel=SMOOTH_KERNELS, dims=True)
SCENES = {"disks": _disks, "jelly": _jelly}


def problem_scene(params, problem, variant, ledger=False):
    """The scene of ``problem`` for ``variant``, as the case declares it."""
    return SCENES[problem](params, variant, ledger)


def make_simulation(params, problem, variant, backend="numpy", ledger=False):
    """The simulation of ``problem`` for ``variant`` on ``backend`` (its scene fitted to what the backend implements,
    :func:`~verification.framework.applicable.fit`), in its initial state; with ``ledger``, it books the energy
    ledger (``[output] energy_ledger``). The jelly starts stretched (module docstring)."""
    scene = fit(problem_scene(params, problem, variant, ledger), backend, variant.allows(ALLOWS)).scene
    sim = Simulation(scene, backend=backend)
    if problem == "jelly":
        s = params.jelly_stretch
        if sim.F is not None:  # isochoric in the plane; the slab's depth (3D) unstretched
            sim.F = np.broadcast_to(np.diag([1.0 + s, 1.0 / (1.0 + s), 1.0][:scene.dim]), sim.F.shape)
        else:  # a fluid: its energy is that of its volume
            sim.J = np.full(sim.J.shape, 1.0 + s)
    return sim


def _energies(sim):
    d = sim.diagnostics()
    return (d["time"], d["kinetic"] + d["kinetic_affine"] + d["kinetic_modes"], d["elastic"], d["total_energy"],
            *(d[f"ledger_{term}"] for term in TERMS))


def run_variant(job):
    """Run ``job = (params, problem, key, backend)`` to its end time: energies and the cumulative energy ledger every
    step, VTK frames."""
    params, problem, key, backend = job
    sim = make_simulation(params, problem, VARIANT[key], backend, ledger=True)
    run = record(sim, _energies, params.frames, t_end=sim.scene.time.t_end)
    a = np.array(run.rows)
    return {"t": a[:, 0], "kinetic": a[:, 1], "elastic": a[:, 2], "total": a[:, 3],
            "ledger": {term: a[:, 4 + k] for k, term in enumerate(TERMS)}, "steps": sim.step_count,
            "n_particles": sim.n_particles, "wall_s": run.wall_s, "frames": run.frames}


def run(params=Params(), backend="numpy", executor=None):
    """Run every problem × variant that the backend implements (through ``executor``; default: in this process); the
    others, and the orderings that need them, are listed as not applicable."""
    executor = executor or Executor(workers=1)
    triage = Triage(backend)
    jobs = [(params, problem, key, backend) for problem in params.problems for key in params.variants
            if triage.scene(_gain_name(problem, key), problem_scene(params, problem, VARIANT[key]),
                            VARIANT[key].allows(ALLOWS), run=_run_name(problem, key))]
    if not jobs:
        raise triage.nothing_ran()
    for problem in params.problems:
        for more, less, _ in ORDERINGS:
            lacking = [r for k in (more, less) for r in triage.reasons(_run_name(problem, k))]
            if {more, less} <= set(params.variants) and lacking:
                triage.skip(_ordering_name(problem, more, less), lacking)
    runs = executor.map(run_variant, jobs)
    out = {problem: {} for problem in params.problems}
    for (_, problem, key, _), r in zip(jobs, runs):
        out[problem][key] = r
    return {"params": params, "backend": backend, "runs": {p: r for p, r in out.items() if r}, **triage.record()}


# ------------------------------------------------------------------------------------------ checks
def budget(r):
    """Initial and final total energy, lost fraction, largest relative gain and its bound for one run."""
    e0 = r["total"][0]
    return {"E0": e0, "E_end": r["total"][-1], "lost": 1.0 - r["total"][-1] / e0,
            "gain": float(np.max(r["total"] - e0) / e0), "gain_bound": gain_bound(r["t"], r["elastic"], e0)}


def _run_name(problem, key):
    return f"{problem}: {VARIANT[key].label}"


def _gain_name(problem, key):
    return f"{problem}: {VARIANT[key].label} energy gain max(E-E0)/E0"


def _ordering_name(problem, more, less):
    return f"{problem}: {VARIANT[more].label} loses more than {VARIANT[less].label}"


def checks(result):
    """No scheme gains energy beyond the O(Δt) bound; theory's ordering of losses (module docstring)."""
    out = []
    for problem, runs in result["runs"].items():
        b = {key: budget(r) for key, r in runs.items()}
        for key, x in b.items():
            out.append(Check(_gain_name(problem, key), x["gain"], "<=",
                             x["gain_bound"], "symplectic Euler: Δt·max‖dV/dt‖/E0 (modified energy, O(Δt))"))
        for more, less, why in ORDERINGS:
            if more in b and less in b:
                out.append(Check(_ordering_name(problem, more, less), b[more]["lost"] - b[less]["lost"], ">", 0.0,
                                 why))
    return out


def table(result, problem):
    """The page's table of ``problem``: per scheme, its energy at the start and the end, what it lost and gained."""
    header = ("scheme", "particles", "steps", "E0", "E_end", "lost fraction", "max gain", "gain bound",
              "wall time [s]")
    rows = []
    for key, r in result["runs"][problem].items():
        x = budget(r)
        rows.append((VARIANT[key].label, r["n_particles"], r["steps"], f"{x['E0']:.6g}", f"{x['E_end']:.6g}",
                     f"{x['lost']:.4f}", f"{x['gain']:.2e}", f"{x['gain_bound']:.2e}", f"{r['wall_s']:.2f}"))
    return Table(header, tuple(rows))


# ----------------------------------------------------------------------------------------- figures
def plot_parts(result, problem, path):
    """One panel per scheme: kinetic, elastic and total energy over E0 against time."""
    plt = pyplot()
    runs = result["runs"][problem]
    cols = min(3, len(runs))
    rows = -(-len(runs) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), sharex=True, sharey=True, squeeze=False)
    for ax, (key, r) in zip(axes.flat, runs.items()):
        e0 = r["total"][0]
        for name, style in (("kinetic", "-"), ("elastic", "-"), ("total", "k-")):
            ax.plot(r["t"], r[name] / e0, style, label=name)
        ax.set_title(VARIANT[key].label, fontsize=9)
        ax.grid(True, alpha=0.3)
    for ax in axes.flat[len(runs):]:
        ax.set_visible(False)
    axes[0, 0].legend(fontsize=8)
    fig.supxlabel("time [s]")
    fig.supylabel("energy / E0")
    return save_figure(fig, path, caption=(
        f"{problem}: kinetic, elastic and total energy over E0 against time, one panel per scheme. Look for the "
        "exchange between kinetic and elastic energy, and a black total line that may fall (transfer "
        "dissipation, most for PIC) but never rises above 1 by more than the O(Δt) gain bound (checked)."))


def plot_totals(result, problem, path):
    """Total energy over E0 against time, all schemes on one axis."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key, r in result["runs"][problem].items():
        ax.plot(r["t"], r["total"] / r["total"][0], label=VARIANT[key].label)
    ax.set(xlabel="time [s]", ylabel="total energy / E0", title=f"{problem}: total energy per scheme")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path, caption=(
        f"{problem}: total energy over E0 against time for every scheme on one axis. Look for the order of the "
        "curves at the end: PIC lowest, FLIP(0.95) below FLIP(1), MLS-MPM below PolyPIC (each checked); FLIP(1) "
        "against APIC is not ordered by theory."))


def plot_ledger(result, problem, path):
    """One panel per scheme: the cumulative energy ledger's terms as stacked areas and the measured change of total
    energy, over E0, against time."""
    panels = [(VARIANT[key].label, r["t"], {term: v / r["total"][0] for term, v in r["ledger"].items()},
               r["total"] / r["total"][0] - 1.0, None) for key, r in result["runs"][problem].items()]
    return ledger_figure(panels, path, "cumulative energy / E0", caption=(
        f"{problem}: where each scheme's energy went, over E0 against time: the energy ledger's cumulative terms "
        "stacked above zero (energy a stage added) and below (energy it took), and the measured change of total "
        "energy in black, their sum. Look for the transfers (P2G blue, G2P orange) taking most of PIC's loss, FLIP's "
        "G2P adding energy that its P2G takes back, PolyPIC's G2P taking nothing (its advection, purple, is its "
        "modes' energy changing as the particles move), and the integration error (green) oscillating, symplectic "
        "Euler's modified energy; the energy_ledger case checks the signs theory fixes."))


def report(result, out_dir):
    """Write the energy plots, VTK series (``vtk/PROBLEM/KEY/particles.pvd``) and ``energy.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths, page = [], Page("Energy budget per scheme")
    for problem, runs in result["runs"].items():
        paths += [plot_parts(result, problem, out / f"energy_{problem}.png"),
                  plot_totals(result, problem, out / f"energy_total_{problem}.png"),
                  plot_ledger(result, problem, out / f"energy_ledger_{problem}.png")]
        paths += [write_series(out / "vtk" / problem / key, r["frames"]) for key, r in runs.items()]
        page.add(Heading(problem), table(result, problem), Figure(f"energy_{problem}.png", "parts"),
                 Figure(f"energy_total_{problem}.png", "totals"), Figure(f"energy_ledger_{problem}.png", "ledger"))
    page.add(Heading("Checks"), Checks(checks(result)))
    return paths + [write_page(page, out / "energy.md")]


#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, main_figure=MAIN_FIGURE)
