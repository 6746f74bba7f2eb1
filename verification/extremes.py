r"""Stability at extremes: the largest stable CFL number per scheme, across ν, E and particles per cell.

The test body is an elastic block (fixed-corotated, :math:`\rho = 1`) in the middle of a unit square
with slip walls, started from a smooth shear field plus uniform random noise of the same size, both
scaled to a fixed Mach number :math:`M = |v| / c` (:math:`c` the P-wave speed), so that every
wavelength down to the grid's is excited. A run of ``steps`` steps at CFL number :math:`C` (the engine's
rule :math:`\Delta t = C\Delta x / (c + |v|_{max})`) is *stable* when it stays finite, inside the domain,
and its total energy never exceeds ``energy_factor`` times the initial one. For each scheme and
condition the case runs :math:`C` = ``guaranteed_cfl`` first, then bisects between the last stable and
the first unstable :math:`C` up to ``cfl_max``.

Theory behind the checks:

* **CFL ≤ 0.3 is stable everywhere.** Symplectic Euler on :math:`M\ddot u = -Ku` is stable for
  :math:`\Delta t \le 2/\omega_{max}`. With lumped masses and quadratic B-splines (exact quadrature)
  the 1D Fourier symbol of :math:`M^{-1}K` at :math:`\theta = \pi` is
  :math:`4\sin^2(\theta/2)\,(2 + \cos\theta)/3 \cdot c^2/\Delta x^2 = \tfrac43 c^2/\Delta x^2`,
  so :math:`C_{crit} = \sqrt 3`; in 2D the tensor-product symbol takes its maximum on the axes, where
  it is the same. With one particle at each cell centre the symbol is that of linear elements,
  :math:`4 c^2/\Delta x^2`, so :math:`C_{crit} = 1`. The CFL rule uses the P-wave speed, the largest
  wave speed for every :math:`\nu` and :math:`E`. The check's 0.3 leaves a factor above three for what
  the linear analysis leaves out: particle quadrature, the transfers, boundaries, nonlinear response.
* **E does not move the limit.** Scaling :math:`E \to sE` with :math:`\rho`, :math:`M` fixed scales
  :math:`v, c` by :math:`\sqrt s`, :math:`\Delta t` by :math:`1/\sqrt s`, stresses by :math:`s`; positions
  and :math:`F` follow the same trajectory (dimensional analysis), so the limit found must agree across
  :math:`E` to within the bisection's resolution.
* **The cell-crossing detector measures** :math:`\max_p |x_p^{n+1} - x_p^n|/\Delta x`. On a block
  translating at speed :math:`V` every scheme transports the field exactly (partition of unity), so the
  detector must read :math:`C V/(c + V)`, more than one cell per step for :math:`V = 10c`, :math:`C = 1.5`.

On a backend that implements a part (:mod:`verification.framework.applicable`): each scheme runs if the backend has it.
The linear analysis holds for any material with its P-wave speed :math:`c`, which the CFL rule and the Mach number use,
so the block may be of another hyperelastic material the backend has, of the density and P-wave speed of the condition's
solid (a fluid then has :math:`K = \rho c^2/\gamma`: the E sweep scales it as it scales E, and the ν values only
stiffen it); the slip walls may be another static wall the backend has (a static wall's projection never adds
energy), the translating block's open walls the backend's walls on a padded domain. Where the backend fixes the
substitute's stiffness, the E sweep changes nothing and its spread check is not applicable. The others are not
applicable.
"""

import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mpmref import DomainExitError, InstabilityError, NonFiniteError, SceneBuilder, Simulation
from mpmref.run.stability import StabilityWarning

from .framework.applicable import Allow, Triage, fit
from .framework.case import VerificationCase
from .framework.common import Check, Finding
from .framework.executor import Executor
from .framework.page import Checks, Figure, Heading, Page, Table, Text, write_page
from .framework.report import pyplot, save_figure

#: scheme label -> method options (the force is the engine's default, MLS, unless stated)
SCHEMES = {
    "pic": {"scheme": "pic", "force": "classic"},
    "flip": {"scheme": "flip", "flip_alpha": 0.95},
    "apic": {"scheme": "apic", "force": "classic"},
    "mls": {"scheme": "mls"},
    "polypic": {"scheme": "polypic"},
}


#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "extremes.png"
#: what the claims let a backend that implements a part change (module docstring)
ALLOWS = Allow(materials="substitute", walls="static", friction=True)
#: the schemes whose label names their force (APIC with the classic force, MLS-MPM); the others' claims hold for
#: either force, so a backend may run them with its own
NAMES_FORCE = ("apic", "mls")


def allows(scheme):
    """:data:`ALLOWS` for ``scheme``, with the force free where its label does not name it."""
    return ALLOWS if scheme in NAMES_FORCE else replace(ALLOWS, force=True)

@dataclass(frozen=True)
class Condition:
    """Material and sampling of one stability probe: Young's modulus, Poisson ratio, particles per cell."""

    E: float = 1.0e4
    nu: float = 0.3
    ppc: int = 4

    def label(self, base):
        changed = [f"{name} = {getattr(self, key):g}" for key, name in (("nu", "ν"), ("E", "E"), ("ppc", "ppc"))
                   if getattr(self, key) != getattr(base, key)]
        return ", ".join(changed) or f"base (E = {self.E:g}, ν = {self.nu:g}, ppc = {self.ppc})"


@dataclass(frozen=True)
class Params:
    """Schemes, conditions and probe settings (see the module docstring).

    ``nus``, ``youngs``, ``ppcs`` are varied one at a time away from ``base``; ``ppcs`` must be perfect
    squares (regular sampling). ``crossing_speed`` is the translating block's speed in P-wave speeds and
    ``crossing_cfl`` its CFL number.
    """

    schemes: tuple = tuple(SCHEMES)
    kernel: str = "quadratic"
    base: Condition = Condition()
    nus: tuple = (0.3, 0.499)
    youngs: tuple = (1.0e2, 1.0e4, 1.0e9)
    ppcs: tuple = (1, 4)
    cells: int = 16
    steps: int = 40
    mach: float = 0.05
    energy_factor: float = 10.0
    guaranteed_cfl: float = 0.3
    cfl_max: float = 3.0
    bisections: int = 5
    crossing_speed: float = 10.0
    crossing_cfl: float = 1.5
    seed: int = 7

    @classmethod
    def quick(cls):
        return cls()

    @classmethod
    def full(cls):
        return cls(nus=(0.3, 0.4, 0.45, 0.49, 0.499), youngs=(1.0e2, 1.0e4, 1.0e6, 1.0e9), ppcs=(1, 4, 9, 16),
                   steps=80, bisections=8)

    def conditions(self):
        """The base condition, then each ν, E and ppc value that differs from it (one change at a time)."""
        out = [self.base]
        out += [Condition(self.base.E, nu, self.base.ppc) for nu in self.nus if nu != self.base.nu]
        out += [Condition(E, self.base.nu, self.base.ppc) for E in self.youngs if E != self.base.E]
        out += [Condition(self.base.E, self.base.nu, ppc) for ppc in self.ppcs if ppc != self.base.ppc]
        return out


# ----------------------------------------------------------------------------------------------- probes
def block_scene(params, scheme, condition, cfl):
    """The test block: a fixed-corotated square of half the domain's side, slip walls, CFL time steps."""
    return (SceneBuilder(dim=2, name=f"extremes_{scheme}").grid(size=1.0, cells=params.cells)
            .method(kernel=params.kernel, **SCHEMES[scheme])
            .material("m", "fixed_corotated", E=condition.E, nu=condition.nu, rho=1.0)
            .box("m", lower=[0.25, 0.25], upper=[0.75, 0.75], ppc=condition.ppc)
            .walls("slip").time(cfl=cfl).output(every=1, checkpoint=False).build())


def perturbation(x, speed, seed):
    r"""Smooth shear :math:`(\sin 4\pi y, \sin 4\pi x)` plus uniform noise in :math:`[-1, 1]^2`, times ``speed``."""
    rng = np.random.default_rng(seed)
    smooth = np.stack([np.sin(4.0 * np.pi * x[:, 1]), np.sin(4.0 * np.pi * x[:, 0])], axis=1)
    return speed * (smooth + rng.uniform(-1.0, 1.0, x.shape))


def block_simulation(params, scheme, condition, cfl, backend="numpy", out_dir=None):
    """A :class:`~mpmref.run.simulation.Simulation` of the test block with its initial :func:`perturbation`."""
    sim = Simulation(fit(block_scene(params, scheme, condition, cfl), backend, allows(scheme)).scene, backend=backend,
                     out_dir=out_dir)
    sim.v = perturbation(sim.x, params.mach * sim.scene.max_wave_speed(), params.seed)
    return sim


def total_energy(sim):
    """Kinetic (with affine and PolyPIC modes) plus elastic energy of the current state."""
    return sim.diagnostics()["total_energy"]


def probe(sim, steps, energy_factor):
    """:func:`_probe` without the engine's stability warnings: this case runs past the limits on purpose."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", StabilityWarning)
        return _probe(sim, steps, energy_factor)


def _probe(sim, steps, energy_factor):
    """Run ``steps`` steps; returns whether they were stable, why not, when, and the cell-crossing reading.

    ``crossing`` is the detector: the largest :math:`|x_p^{n+1} - x_p^n| / \\Delta x` over particles and
    steps. The engine's :class:`~mpmref.errors.NonFiniteError`, :class:`~mpmref.errors.InstabilityError` (an
    unbounded velocity change that takes a particle out of the domain) and
    :class:`~mpmref.errors.DomainExitError` are caught and recorded as breaks. A simulation with an
    output folder writes what :meth:`~mpmref.run.simulation.Simulation.run` writes (a frame every
    ``scene.output.every`` steps).
    """
    e0, dx, first = total_energy(sim), sim.scene.grid.dx, sim.step_count
    crossing, peak, x_old = 0.0, 1.0, sim.x

    def outcome(kind, step):
        return {"stable": kind is None, "kind": kind, "step": step, "crossing": crossing, "energy_peak": peak}

    def watch(sim):
        nonlocal crossing, peak, x_old
        crossing = max(crossing, float(np.max(np.linalg.norm(sim.x - x_old, axis=1))) / dx)
        peak, x_old = max(peak, total_energy(sim) / e0), sim.x
        if not peak <= energy_factor:
            raise _EnergyBreak

    try:
        sim.run(steps=steps, each_step=watch)
    except _EnergyBreak:
        return outcome("energy", sim.step_count - first)
    except NonFiniteError:  # a step that raises is not taken: it is the next one
        return outcome("non-finite", sim.step_count - first + 1)
    except InstabilityError:  # an unbounded velocity change that takes a particle out of the domain
        return outcome("unbounded", sim.step_count - first + 1)
    except DomainExitError:
        return outcome("left domain", sim.step_count - first + 1)
    return outcome(None, steps)


class _EnergyBreak(Exception):
    """The total energy grew past the probe's factor: the end of :func:`_probe`'s run."""


@dataclass(frozen=True)
class Bisection:
    """One sweep point: the stability limit of ``scheme`` under ``condition`` (picklable)."""

    params: Params
    scheme: str
    condition: Condition
    backend: str = "numpy"


def is_stable(item, cfl):
    """:func:`probe` the block of ``item`` at CFL number ``cfl``."""
    sim = block_simulation(item.params, item.scheme, item.condition, cfl, item.backend)
    return probe(sim, item.params.steps, item.params.energy_factor)


def bisect(item):
    """Largest stable CFL (``limit``), the smallest unstable one found (``unstable_at``), how and when it broke,
    and the cell-crossing reading at the limit.

    Starts at ``guaranteed_cfl``; if that holds, brackets ``[guaranteed_cfl, cfl_max]``, else ``[0, guaranteed_cfl]``.
    """
    p = item.params
    first = is_stable(item, p.guaranteed_cfl)
    lo, hi = (p.guaranteed_cfl, p.cfl_max) if first["stable"] else (0.0, p.guaranteed_cfl)
    lo_run, hi_run = (first, is_stable(item, hi)) if first["stable"] else (None, first)
    if hi_run["stable"]:
        return {"limit": hi, "unstable_at": None, "kind": None, "break_step": None, "crossing": hi_run["crossing"]}
    for _ in range(p.bisections):
        mid = 0.5 * (lo + hi)
        run_mid = is_stable(item, mid)
        if run_mid["stable"]:
            lo, lo_run = mid, run_mid
        else:
            hi, hi_run = mid, run_mid
    return {"limit": lo, "unstable_at": hi, "kind": hi_run["kind"], "break_step": hi_run["step"],
            "crossing": lo_run["crossing"] if lo_run else float("nan")}


def crossing_scene(params, scheme):
    """The block translating along x at ``crossing_speed`` P-wave speeds, on a grid long enough for the run."""
    cells_x = params.cells + math.ceil(params.steps * params.crossing_cfl) + 4
    dx = 1.0 / params.cells
    return (SceneBuilder(dim=2, name=f"crossing_{scheme}").grid(size=[cells_x * dx, 1.0], dx=dx)
            .method(kernel=params.kernel, **SCHEMES[scheme])
            .material("m", "fixed_corotated", E=params.base.E, nu=params.base.nu, rho=1.0)
            .box("m", lower=[0.25, 0.25], upper=[0.75, 0.75], ppc=params.base.ppc)
            .walls("open").time(cfl=params.crossing_cfl).build())


def crossing(item):
    """Run the translating block (``item = (params, scheme, backend)``); detector reading and prediction."""
    params, scheme, backend = item
    sim = Simulation(fit(crossing_scene(params, scheme), backend, allows(scheme)).scene, backend=backend)
    c = sim.scene.max_wave_speed()
    speed = params.crossing_speed * c
    sim.v = np.tile([speed, 0.0], (sim.n_particles, 1))
    result = probe(sim, params.steps, params.energy_factor)
    return {**result, "predicted": params.crossing_cfl * speed / (c + speed)}


def run(params=Params(), backend="numpy", executor=None):
    """Bisect every scheme under every condition, run the translating block; ``executor`` default: this process. A
    scheme the backend does not implement is listed as not applicable, with its checks."""
    executor = executor or Executor(workers=1)
    triage = Triage(backend)
    conditions = params.conditions()
    schemes = [s for s in params.schemes if _applicable(params, s, conditions, triage)]
    if not schemes:
        raise triage.nothing_ran()
    items = [Bisection(params, s, cond, backend) for cond in conditions for s in schemes]
    limits = executor.map(bisect, items)
    crossings = executor.map(crossing, [(params, s, backend) for s in schemes])
    rows = [{"condition": it.condition, "scheme": it.scheme, **lim} for it, lim in zip(items, limits)]
    fixed = _fixed_stiffness(params, schemes, backend)
    for s in fixed:
        triage.skip(f"{s}: spread of the CFL limit over E", ["the backend fixes the stiffness of the material it runs: "
                                                             "the E sweep varies nothing"])
    return {"params": params, "backend": backend, "executor": executor.describe(), "rows": rows,
            "crossing": dict(zip(schemes, crossings)), "fixed_stiffness": fixed, **triage.record()}


def _applicable(params, scheme, conditions, triage):
    """Whether the backend implements ``scheme``'s block under every condition and its translating block."""
    name = f"{scheme}: every check (largest stable CFL per condition, its spread over E, cell-crossing detector)"
    scenes = [(f"{scheme}, {c.label(params.base)}", block_scene(params, scheme, c, params.guaranteed_cfl))
              for c in conditions] + [(f"{scheme}: translating block", crossing_scene(params, scheme))]
    fitted = [triage.fit(run, scene, allows(scheme)) for run, scene in scenes]
    if any(f is None for f in fitted):
        triage.skip(name, [r for run, _ in scenes for r in triage.reasons(run)])
        return False
    return True


def _fixed_stiffness(params, schemes, backend):
    """The schemes whose blocks across the E sweep have one wave speed: the backend fixes the stiffness of the
    material it runs, so the sweep varies nothing (its spread check is not applicable)."""
    youngs = [c for c in params.conditions() if c.nu == params.base.nu and c.ppc == params.base.ppc]
    return [s for s in schemes if len({fit(block_scene(params, s, c, params.guaranteed_cfl), backend, allows(s))
                                       .scene.max_wave_speed() for c in youngs}) == 1 < len(youngs)]


def resolution(params):
    """Width of the bisection's final bracket above ``guaranteed_cfl``."""
    return (params.cfl_max - params.guaranteed_cfl) / 2**params.bisections


def sweep(result, scheme, key):
    """``[(value, limit)]`` of ``scheme`` over the conditions that differ from the base only in ``key``."""
    base = result["params"].base
    others = [k for k in ("E", "nu", "ppc") if k != key]
    return sorted((getattr(r["condition"], key), r["limit"]) for r in result["rows"] if r["scheme"] == scheme
                  and all(getattr(r["condition"], k) == getattr(base, k) for k in others))


def checks(result):
    """The three theory claims of the module docstring as checks."""
    p = result["params"]
    out = []
    for r in result["rows"]:
        out.append(Check(f"{r['scheme']}, {r['condition'].label(p.base)}: largest stable CFL", r["limit"], ">=",
                         p.guaranteed_cfl, "linear stability of lumped-mass symplectic Euler: CFL_crit = sqrt(3) "
                         "(quadratic B-spline), 1 (one particle per cell); margin for quadrature, transfers, "
                         "nonlinearity"))
    for s in result["crossing"]:
        if s in result.get("fixed_stiffness", ()):
            continue
        values, limits = zip(*sweep(result, s, "E"))
        out.append(Check(f"{s}: spread of the CFL limit over E = {min(values):g} .. {max(values):g}",
                         max(limits) - min(limits), "<=", resolution(p),
                         "dimensional analysis: at fixed Mach number the trajectory does not depend on E"))
    for s, c in result["crossing"].items():
        out.append(Check(f"{s}: cell-crossing detector on the translating block", c["crossing"], ">", 1.0,
                         f"the block moves C V/(c + V) = {c['predicted']:.4f} cells per step"))
        out.append(Check(f"{s}: detector reading - C V/(c + V)", abs(c["crossing"] - c["predicted"]), "<=",
                         1e-9 * c["predicted"], "partition of unity: a uniform translation is transported exactly"))
    return out


def findings(result):
    """The largest stable CFL number of each scheme on the base block: measured, not judged (only the
    guaranteed 0.3 is checked)."""
    p = result["params"]
    out = []
    for r in (r for r in result["rows"] if r["condition"] == p.base):
        if r["unstable_at"] is None:
            how = f"every probe up to the search's top, CFL {p.cfl_max:g}, was stable"
        else:
            how = (f"the first unstable probe, CFL {r['unstable_at']:.3f}, broke by {r['kind']} at step "
                   f"{r['break_step']}")
        out.append(Finding(f"{r['scheme']}: largest stable CFL number, base block", r["limit"],
                           f"Measured by bisection to within {resolution(p):.3g} over {p.steps} steps; {how}. "
                           f"Only CFL >= {p.guaranteed_cfl:g} is checked; the limit itself depends on the scheme "
                           "and the run length."))
    return out


# ----------------------------------------------------------------------------------------------- report
def _cell(row):
    if row["unstable_at"] is None:
        return f"≥ {row['limit']:.3g}"
    return f"{row['limit']:.3f} ({row['kind']} at {row['unstable_at']:.3f}, step {row['break_step']})"


def _by_condition(result, cell):
    """A :class:`~verification.framework.page.Table`: one row per condition, one column per scheme, ``cell(row)`` in
    each."""
    p = result["params"]
    schemes = list(result["crossing"])  # the schemes that ran
    return Table(("condition", *schemes), tuple(
        (cond.label(p.base), *(cell(r) for s in schemes for r in result["rows"]
                               if r["scheme"] == s and r["condition"] == cond)) for cond in p.conditions()))


def table(result):
    """The largest stable CFL number per condition and scheme, with how the first unstable probe broke."""
    return _by_condition(result, _cell)


def detector_table(result):
    """The cell-crossing detector (cells per step) at each largest stable CFL number."""
    return _by_condition(result, lambda r: f"{r['crossing']:.3f}")


def crossing_table(result):
    """The table of the translating block: detector reading, prediction, stability."""
    header = ("scheme", "detector (cells / step)", "predicted C V/(c+V)", "stable", "energy peak / initial")
    return Table(header, tuple((s, f"{c['crossing']:.6f}", f"{c['predicted']:.6f}",
                                "yes" if c["stable"] else c["kind"], f"{c['energy_peak']:.6f}")
                               for s, c in result["crossing"].items()))


def _plot(result, path):
    plt = pyplot()
    p = result["params"]
    sweeps = (("nu", "Poisson ratio ν", "linear"), ("E", "Young's modulus E", "log"),
              ("ppc", "particles per cell", "linear"))
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for ax, (key, title, scale) in zip(axes, sweeps):
        for s in result["crossing"]:
            ax.plot(*zip(*sweep(result, s, key)), "o-", label=s)
        ax.axhline(p.guaranteed_cfl, color="k", ls="--", lw=1, label="checked bound")
        ax.set_xscale(scale)
        ax.set_xlabel(title)
        ax.set_ylabel("largest stable CFL")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Largest stable CFL number ({p.steps} steps, energy factor {p.energy_factor:g})")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120, caption=(
        f"Largest stable CFL number per scheme as one of ν, E and particles per cell moves away from the base "
        f"block (bisection resolution {resolution(p):.3g}). Look for every point above the dashed line at CFL "
        f"{p.guaranteed_cfl:g} (checked) and flat curves across E (dimensional analysis, checked); how far the "
        "limits sit above the line, and how they move with ν and ppc, is measured, not judged."))


def _representative(result, folder):
    """VTK series (every step) of the base block just past the lowest limit: what breaking looks like."""
    p = result["params"]
    base_rows = [r for r in result["rows"] if r["condition"] == p.base and r["unstable_at"] is not None]
    if not base_rows:
        return None
    row = min(base_rows, key=lambda r: r["limit"])
    sim = block_simulation(p, row["scheme"], p.base, row["unstable_at"], result["backend"], out_dir=folder)
    sim.write_output()
    return row, probe(sim, p.steps, p.energy_factor)


def report(result, out_dir):
    """Write ``extremes.md``, ``extremes.png`` and a VTK series of a breaking run; returns the summary path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    p = result["params"]
    png = _plot(result, out / "extremes.png")
    page = Page("Stability at extremes", [
        Text(f"{p.cells}x{p.cells} grid, {p.kernel} kernel, {p.steps} steps per probe, Mach {p.mach:g}, "
             f"stable = finite, inside the domain and total energy <= {p.energy_factor:g} x initial; bisection "
             f"resolution {resolution(p):.3g}; backend `{result['backend']}`, sweep run in {result['executor']}."),
        Text("Largest stable CFL number (and how the first unstable probe broke):"), table(result),
        Figure(png.name, "limits"),
        Text("Cell-crossing detector, max |x_p(n+1) - x_p(n)| / dx, at the largest stable CFL number:"),
        detector_table(result),
        Text(f"Translating block: speed {p.crossing_speed:g} c at CFL {p.crossing_cfl:g}:"), crossing_table(result)])
    rep = _representative(result, out / "vtk_breaking")
    if rep:
        row, outcome = rep
        verdict = "stable" if outcome["stable"] else outcome["kind"]
        page.add(Text(f"Representative run (`vtk_breaking/particles.pvd`): {row['scheme']} at CFL "
                      f"{row['unstable_at']:.3f}, outcome: {verdict} at step {outcome['step']}."))
    page.add(Heading("Checks"), Checks(checks(result)))
    return write_page(page, out / "extremes.md")


#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings, main_figure=MAIN_FIGURE)
