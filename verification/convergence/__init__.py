r"""Convergence under refinement: the vibrating bar and an axis-aligned manufactured solution.

Each *series* (problem × scheme × force × kernel, see :class:`Series`) runs on a list of grids at the
same CFL number and particles per cell; its error is measured against the analytic solution at the
end time and the slope of :math:`\log e` against :math:`\log \Delta x` is fitted by least squares.

* Error measures (relative RMS over particles; :math:`X_p` is the material point, :math:`t_N` the end):

  .. math::

      e_u = \frac{1}{U}\Big(\frac1n\sum_p |x_p - X_p - u(X_p, t_N)|^2\Big)^{1/2}, \qquad
      e_v = \frac{1}{V}\Big(\frac1n\sum_p |v_p - v(X_p, t_N - \Delta t/2)|^2\Big)^{1/2}

  with :math:`U, V` the displacement and velocity amplitudes. Symplectic Euler makes :math:`v_p^{n}`
  a half-step velocity (it moved :math:`x_p` from :math:`t_{n-1}` to :math:`t_n`), so it is compared at
  :math:`t_N - \Delta t/2`, and the run starts from :math:`v(X, -\Delta t/2)` (and
  :math:`C_p = \nabla v(X, -\Delta t/2)`).
* Checks, for series with an ``expected_rate`` :math:`r`: :math:`|s - r| \le` ``rate_tolerance`` for the
  fitted slope :math:`s` of :math:`e_u`, and :math:`e_u \le C (k\Delta x)^r` on the finest grid, with
  :math:`k` the mode's wavenumber. :math:`C = 1` for second-order series (the leading error of a
  consistent second-order discretisation of a mode is :math:`c_2 (k\Delta x)^2` with an :math:`O(1)`
  constant :math:`c_2 \ll 1`); for PIC, :func:`pic_bound_constant`. Series without an expected rate are
  findings (:func:`findings`): their fitted slope is reported and plotted, never judged.

See ``docs/convergence.md`` for the problems, the boundary treatment and how to read the plots.

On a backend that implements a part (:mod:`verification.framework.applicable`): a series runs if the backend has its
scheme, force, kernel and material as declared. The analytic solutions are those of their materials (the bar's of a
fixed-corotated material with :math:`\nu = 0`, the MMS's of a Neo-Hookean one), so no material is substituted; only
the open walls of zero width, which act on no node, may be the backend's own. The other series, with their checks or
findings, are not applicable.
"""

import math
import time as _time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpmref.backends import make_backend
from mpmref.scene.sampling import sample_particles
from mpmref.steppers.limits import cfl_time_step

from ..framework.applicable import Allow, Triage, fit
from ..framework.case import VerificationCase
from ..framework.common import Check, Finding
from ..framework.executor import Executor
from ..framework.page import Checks, Figure, Heading, Items, Page, Table, Text, write_page
from ..framework.report import pyplot, save_figure
from .problems import PROBLEMS
from .stepping import TREATMENTS, advance

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "convergence_bar.png"

SCHEME_NAMES = {("apic", "classic"): "APIC", ("mls", "mls"): "MLS-MPM", ("pic", "classic"): "PIC"}
CFL = 0.4
#: what a backend that implements a part may change: its own walls for the open ones of zero width (module docstring)
ALLOWS = Allow(walls="open")


def pic_bound_constant(cfl):
    r"""Constant :math:`C` of the first-order PIC bound :math:`e_u \le C\, k\Delta x`.

    PIC's transfer pair G2P∘P2G multiplies a resolved Fourier mode by
    :math:`1 - \sigma^2 (k\Delta x)^2/2`, where :math:`\sigma^2 = 2 \cdot \tfrac14` is the variance (in
    :math:`\Delta x^2`) of two quadratic B-spline smoothings (a B-spline of degree :math:`p` has variance
    :math:`(p+1)/12`); this is the dissipation that motivated APIC (Jiang et al. 2015). A run to
    :math:`T/4` takes :math:`n = \pi / (2\, \mathrm{CFL}\, k\Delta x)` steps, so the velocity amplitude
    lost is about :math:`n (k\Delta x)^2 / 4 = \pi k\Delta x / (8\,\mathrm{CFL})`; the displacement, an
    integral of the velocity, loses less than that fraction.
    """
    return math.pi / (8.0 * cfl)


@dataclass(frozen=True)
class Series:
    r"""One refinement study: a problem solved by one scheme/force/kernel on every grid of its problem.

    ``gradient`` is the velocity gradient of the F update (``"mls"``: :math:`C_p`; ``"classic"``:
    :math:`\sum_i v_i \nabla w_{ip}^T`; ``None``: the force's, as in a scene); ``ppa`` overrides the study's
    particles per cell per axis; ``amplitude`` overrides the problem's (the bar's :math:`v_0`, the MMS's :math:`A`);
    ``fixed_end`` is the boundary treatment (``"mirror"`` or ``"zero"``, see :mod:`.stepping`);
    ``expected_rate`` ``None`` marks a finding; ``bound_constant`` is :math:`C` of the finest-grid bound;
    ``why`` says where the expected rate comes from, or what a finding shows.
    """

    problem: str
    scheme: str
    force: str
    kernel: str
    expected_rate: float | None = 2.0
    bound_constant: float = 1.0
    amplitude: float | None = None
    fixed_end: str = "mirror"
    gradient: str | None = None
    ppa: int | None = None
    why: str = "second-order consistent transfer, force and time integration"

    @property
    def label(self):
        if self.gradient in (None, self.force):
            text = f"{SCHEME_NAMES[(self.scheme, self.force)]} {self.kernel}"
        else:
            text = f"APIC {self.kernel}, {self.force} force, {self.gradient} F update"
        if self.ppa is not None:
            text += f", {self.ppa} particles per cell per axis"
        if self.amplitude is not None:
            text += f", {'v0' if self.problem == 'bar' else 'A'} = {self.amplitude:g}"
        return text + (", nodes at x <= 0 zeroed" if self.fixed_end == "zero" else "")

    def build_problem(self):
        key = "v0" if self.problem == "bar" else "amplitude"
        overrides = {} if self.amplitude is None else {key: self.amplitude}
        return PROBLEMS[self.problem](**overrides)

    def method(self):
        gradient = {} if self.gradient is None else {"velocity_gradient": self.gradient}
        return {"scheme": self.scheme, "force": self.force, "kernel": self.kernel, **gradient}


MLS_QUADRATIC = ("with the quadratic kernel and 2 particles per cell per axis MLS-MPM falls at about first "
                 "order; the ablation series of this case locate the O(dx) error in the MLS force, not in the "
                 "F update grad v_p = C_p")


def main_series(problem):
    """APIC (classic force) and MLS-MPM with quadratic and cubic kernels; MLS-MPM quadratic is a finding."""
    out = [Series(problem, "apic", "classic", k) for k in ("quadratic", "cubic")]
    return out + [Series(problem, "mls", "mls", "quadratic", expected_rate=None, why=MLS_QUADRATIC),
                  Series(problem, "mls", "mls", "cubic")]


def ablation_series():
    r"""Where MLS-MPM's quadratic O(Δx) error enters, on the bar: the force and the F update switched apart.

    MLS-MPM differs from APIC with the classic force in two places, the force (:math:`w_{ip} D_p^{-1}(x_i -
    x_p)` for :math:`\nabla w_{ip}`) and the velocity gradient of the F update (:math:`C_p` for
    :math:`\sum_i v_i \nabla w_{ip}^T`). One series swaps only the force, one only the F update, and one
    runs MLS-MPM with 4 particles per cell per axis. All are findings: the slopes are measured, not judged
    (an independent 1D computation found 1.00, 1.69 and about 1.9).
    """
    return [Series("bar", "apic", "mls", "quadratic", expected_rate=None, gradient="classic",
                   why="the MLS force alone (classic F update)"),
            Series("bar", "apic", "classic", "quadratic", expected_rate=None, gradient="mls",
                   why="the MLS F update alone (classic force)"),
            Series("bar", "mls", "mls", "quadratic", expected_rate=None, ppa=4,
                   why="MLS-MPM with twice the particles per axis")]


def pic_series(cfl):
    """PIC on the bar, first order from its transfer dissipation (:func:`pic_bound_constant`)."""
    return Series("bar", "pic", "classic", "quadratic", expected_rate=1.0, bound_constant=pic_bound_constant(cfl),
                  why="PIC's transfer dissipation: O(dx^2) per step over O(1/dx) steps")


def contrast_series():
    """The bar with the crude fixed end and the MMS at a large amplitude: two cautionary facts."""
    zero = Series("bar", "apic", "classic", "quadratic", expected_rate=1.0, fixed_end="zero",
                  why="zeroing the nodes at x <= 0 pins the bar over the stencil's half-width: the boundary "
                      "moves by O(dx)")
    floor = [Series("mms", "apic", "classic", k, expected_rate=None, amplitude=0.05,
                    why="at 20x the amplitude, the particle quadrature of the distorted particle "
                        "lattice puts a floor under the error") for k in ("quadratic", "cubic")]
    return [zero] + floor


@dataclass(frozen=True)
class Params:
    """Grids, series and discretisation of the study.

    ``bar_cells`` / ``mms_cells``: cells along the bar's length / the square's side, one grid per level;
    ``cfl``: the CFL number (P-wave speed plus the largest analytic speed; PIC's bound constant is
    computed for it, rebuild :func:`pic_series` when changing it); ``ppa``: particles per cell per axis
    (regular lattice); ``rate_tolerance``: how far a fitted slope may sit from its expected rate (a fit over
    three or four levels still carries the next error term: an independent 1D computation found
    1.8–2.0 for second-order schemes); ``vtk_cells``: the level of each problem's representative run.
    """

    series: tuple = tuple(main_series("bar") + [pic_series(CFL)] + ablation_series() + main_series("mms")[:2])
    bar_cells: tuple = (16, 32, 64)
    mms_cells: tuple = (16, 32, 64)
    cfl: float = CFL
    ppa: int = 2
    rate_tolerance: float = 0.3
    vtk_cells: int = 32
    vtk_frames: int = 8

    @classmethod
    def quick(cls):
        """The default without the MMS with the cubic kernel (its 64-cell level is the sweep's longest run; the
        cubic kernel's rate is checked on the bar)."""
        return cls(series=cls.series[:-1])

    @classmethod
    def full(cls):
        """Every series to 128 cells; the MMS from 32 cells (k dx = 0.2), where its error is asymptotic."""
        series = main_series("bar") + [pic_series(CFL)] + ablation_series() + main_series("mms") + contrast_series()
        return cls(series=tuple(series), bar_cells=(16, 32, 64, 128), mms_cells=(32, 64, 128))

    def cells(self, problem):
        return self.bar_cells if problem == "bar" else self.mms_cells


@dataclass(frozen=True)
class LevelRun:
    """One sweep point: a series on one grid (picklable, for :class:`~verification.framework.executor.Executor`)."""

    series: Series
    cells: int
    cfl: float
    ppa: int
    backend: str
    frames: int = 0


def time_step(problem, scene, cfl):
    """The CFL step, shortened so that a whole number of steps ends exactly at the problem's end time."""
    dt_cfl = cfl_time_step(cfl, scene.grid.dx, scene.max_wave_speed() + problem.max_speed)
    n = math.ceil(problem.end_time() / dt_cfl)
    return problem.end_time() / n, n


def initial_particles(problem, particles, dt):
    """The half-step start: :math:`v_p = v(X_p, -\\Delta t/2)` and :math:`C_p = \\nabla v(X_p, -\\Delta t/2)`."""
    X = particles.x
    changes = {"v": problem.velocity(X, -0.5 * dt).astype(X.dtype)}
    if particles.C is not None:
        changes["C"] = problem.velocity_gradient(X, -0.5 * dt).astype(X.dtype)
    return particles.with_(**changes)


def rms(a):
    return float(np.sqrt(np.mean(np.sum(a * a, axis=1))))


def errors(problem, particles, X, t, dt):
    """Relative RMS displacement error at ``t`` and velocity error at ``t - dt/2`` (module docstring)."""
    e_u = rms(particles.x - X - problem.displacement(X, t)) / problem.displacement_scale()
    e_v = rms(particles.v - problem.velocity(X, t - 0.5 * dt)) / problem.velocity_scale()
    return e_u, e_v


def _snapshot(problem, particles, X, t):
    u = particles.x - X
    return {"time": t, "x": particles.x.copy(), "id": particles.id.copy(), "velocity": particles.v.copy(),
            "displacement": u, "displacement_exact": problem.displacement(X, t)}


def run_level(item):
    """Run one :class:`LevelRun` to the problem's end time; errors, sizes, wall time (and frames if asked)."""
    series, problem = item.series, item.series.build_problem()
    scene = fit(problem.scene(item.cells, series.method(), item.ppa), item.backend, ALLOWS).scene
    backend = make_backend(item.backend, scene)
    dt, n_steps = time_step(problem, scene, item.cfl)
    particles = sample_particles(scene)
    X = particles.x.copy()
    particles = initial_particles(problem, particles, dt)
    planes = problem.planes(item.cells)
    force = problem.body_force  # of the reference position X, looked up by particle id
    body_force = None if problem.body_force(X, 0.0) is None else (lambda p, t: force(X[p.id], t))
    frame_steps = set(np.linspace(0, n_steps, item.frames + 1).round().astype(int)) if item.frames else set()
    frames, t = [], 0.0
    start = _time.perf_counter()
    for n in range(n_steps):
        if n in frame_steps:
            frames.append(_snapshot(problem, particles, X, t))
        particles = advance(backend, particles, dt, t, planes, series.fixed_end, body_force)
        t = (n + 1) * dt
    wall = _time.perf_counter() - start
    if n_steps in frame_steps:
        frames.append(_snapshot(problem, particles, X, t))
    e_u, e_v = errors(problem, particles, X, t, dt)
    return {"cells": item.cells, "dx": scene.grid.dx, "kdx": problem.wavenumber * scene.grid.dx, "steps": n_steps,
            "dt": dt, "particles": particles.n, "error_u": e_u, "error_v": e_v, "wall_s": wall, "frames": frames}


def fit_slope(dx, err):
    """Least-squares slope and intercept of :math:`\\log e` against :math:`\\log \\Delta x` (NaN for one level)."""
    if len(dx) < 2:
        return float("nan"), float("nan")
    slope, intercept = np.polyfit(np.log(dx), np.log(err), 1)
    return float(slope), float(intercept)


def series_name(series):
    """A series as the not-applicable list names it: its label and what it carries (checks or a finding)."""
    carries = "its finding" if series.expected_rate is None else "its checks"
    return f"{series.problem}: {series.label} ({carries})"


def applicable_series(params, backend, triage):
    """The series of ``params`` whose scene ``backend`` implements (fitted on the coarsest grid); ``triage`` lists
    the others."""
    return [s for s in params.series
            if triage.scene(series_name(s), s.build_problem().scene(params.cells(s.problem)[0], s.method(), params.ppa),
                            ALLOWS, run=f"{s.problem}: {s.label}") is not None]


def _items(params, backend, series_list):
    items = []
    first_of = {}
    for series in series_list:
        if series.fixed_end not in TREATMENTS:
            raise ValueError(f"fixed_end {series.fixed_end!r}: allowed {TREATMENTS}")
        cells = params.cells(series.problem)
        vtk = min(cells, key=lambda c: abs(c - params.vtk_cells))
        first = first_of.setdefault(series.problem, series) == series
        items += [LevelRun(series, c, params.cfl, series.ppa or params.ppa, backend,
                           params.vtk_frames if first and c == vtk else 0)
                  for c in cells]
    return items


def run(params=Params(), backend="numpy", executor=None):
    """Every series on every grid (through ``executor``; default: this process). Returns a result dict."""
    executor = executor or Executor(workers=1)
    triage = Triage(backend)
    series_list = applicable_series(params, backend, triage)
    if not series_list:
        raise triage.nothing_ran()
    items = _items(params, backend, series_list)
    levels = executor.map(run_level, items)
    rows, representative = [], {}
    for series in series_list:
        mine = [lv for it, lv in zip(items, levels) if it.series == series]
        dx = np.array([lv["dx"] for lv in mine])
        slope_u, icpt_u = fit_slope(dx, [lv["error_u"] for lv in mine])
        slope_v, icpt_v = fit_slope(dx, [lv["error_v"] for lv in mine])
        for lv in mine:
            frames = lv.pop("frames")
            if frames:
                representative[series.problem] = {"series": series, "cells": lv["cells"], "frames": frames}
        rows.append({"series": series, "levels": mine, "slope_u": slope_u, "intercept_u": icpt_u,
                     "slope_v": slope_v, "intercept_v": icpt_v})
    return {"params": params, "backend": backend, "executor": executor.describe(), "rows": rows,
            "representative": representative, **triage.record()}


def checks(result):
    """Fitted slope against the expected rate, and the finest grid's error against its bound (module docstring)."""
    tol = result["params"].rate_tolerance
    out = []
    for row in result["rows"]:
        s = row["series"]
        if s.expected_rate is None:
            continue
        r = s.expected_rate
        finest = min(row["levels"], key=lambda lv: lv["dx"])
        name = f"{s.problem}: {s.label}"
        out.append(Check(f"{name}: |fitted slope - {r:g}|", abs(row["slope_u"] - r), "<=", tol,
                         f"fitted slope {row['slope_u']:.3f}; order {r:g}: {s.why}"))
        out.append(Check(f"{name}: e_u on {finest['cells']} cells", finest["error_u"], "<=",
                         s.bound_constant * finest["kdx"] ** r,
                         f"C (k dx)^{r:g} with C = {s.bound_constant:.3g}, k dx = {finest['kdx']:.4g}"))
    return out


def findings(result):
    """The fitted slope of :math:`e_u` of each series without an expected rate: measured, not judged."""
    out = []
    for row in result["rows"]:
        s = row["series"]
        if s.expected_rate is None:
            cells = [lv["cells"] for lv in row["levels"]]
            out.append(Finding(f"{s.problem}: {s.label}: fitted slope of e_u", row["slope_u"],
                               f"e_u falls as Δx^{row['slope_u']:.2f} over {cells[0]}..{cells[-1]} cells; "
                               f"{s.why}."))
    return out


# ---------------------------------------------------------------------------------------------- report
PROBLEM_TITLES = {"bar": "Vibrating bar (T/4)", "mms": "Axis-aligned manufactured solution (t = 1/(2c))"}


def _caption(result, problem):
    rows = [r for r in result["rows"] if r["series"].problem == problem]
    expected = ", ".join(f"{r['series'].label} {r['series'].expected_rate:g}" for r in rows
                         if r["series"].expected_rate is not None)
    found = ", ".join(f"{r['series'].label} {r['slope_u']:.2f}" for r in rows if r["series"].expected_rate is None)
    text = (f"{PROBLEM_TITLES[problem]}: displacement error (left) and velocity error (right) against Δx on "
            f"log-log axes, with least-squares fits (dashed; slopes in the legend). Look for each filled series "
            f"running parallel to its expected slope ({expected}; checked within the rate tolerance)")
    return text + (f", and for the hollow squares, findings reported, not judged (fitted slope {found})." if found
                   else ".")


def _plot(result, problem, path):
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for i, row in enumerate(r for r in result["rows"] if r["series"].problem == problem):
        s, color = row["series"], f"C{i}"
        dx = np.array([lv["dx"] for lv in row["levels"]])
        for ax, key in zip(axes, ("u", "v")):
            err = [lv[f"error_{key}"] for lv in row["levels"]]
            finding = s.expected_rate is None
            ax.loglog(dx, err, "o" if not finding else "s", color=color, mfc="none" if finding else color,
                      label=f"{s.label}{' (finding)' if finding else ''}: slope {row[f'slope_{key}']:.2f}")
            ax.loglog(dx, np.exp(row[f"intercept_{key}"]) * dx ** row[f"slope_{key}"], "--", color=color, lw=1)
    for ax, what in zip(axes, ("displacement error $e_u$ at $t_N$", "velocity error $e_v$ at $t_N - \\Delta t/2$")):
        ax.set_xlabel("$\\Delta x$")
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="best", framealpha=0.6)
    fig.suptitle(PROBLEM_TITLES[problem])
    fig.tight_layout()
    return save_figure(fig, path, caption=_caption(result, problem), dpi=120)


def _write_vtk(rep, folder):
    from mpmref.io.vtk import write_particles_vtu, write_pvd

    folder.mkdir(parents=True, exist_ok=True)
    entries = []
    for k, frame in enumerate(rep["frames"]):
        name = f"particles_{k:06d}.vtu"
        error = frame["displacement"] - frame["displacement_exact"]
        write_particles_vtu(folder / name, frame["x"], {
            "id": frame["id"], "velocity": frame["velocity"], "displacement": frame["displacement"],
            "displacement_exact": frame["displacement_exact"], "displacement_error": error})
        entries.append((frame["time"], name))
    write_pvd(folder / "particles.pvd", entries)
    return folder / "particles.pvd"


def table(result, problem):
    """The page's table of ``problem``: each series' levels, its errors, and its fitted and expected slopes on its
    first row."""
    header = ("series", "cells", "Δx", "k Δx", "steps", "e_u", "e_v", "slope e_u", "slope e_v", "expected")
    rows = []
    for row in (r for r in result["rows"] if r["series"].problem == problem):
        s = row["series"]
        for i, lv in enumerate(row["levels"]):
            fit = (f"{row['slope_u']:.3f}", f"{row['slope_v']:.3f}",
                   "finding" if s.expected_rate is None else f"{s.expected_rate:g}") if i == 0 else ("", "", "")
            rows.append((s.label if i == 0 else "", lv["cells"], f"{lv['dx']:.4g}", f"{lv['kdx']:.4g}", lv["steps"],
                         f"{lv['error_u']:.3e}", f"{lv['error_v']:.3e}", *fit))
    return Table(header, tuple(rows))


def report(result, out_dir):
    """Write ``convergence.md``, a PNG per problem and the representative runs' VTK series; returns the summary."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    p = result["params"]
    page = Page("Convergence under refinement", [Text(
        f"CFL {p.cfl:g}, {p.ppa}x{p.ppa} particles per cell, backend `{result['backend']}`, "
        f"sweep run in {result['executor']}. Slopes are least-squares fits of log(error) against log(Δx).")])
    for problem in dict.fromkeys(r["series"].problem for r in result["rows"]):
        png = _plot(result, problem, out / f"convergence_{problem}.png")
        page.add(Heading(problem), Figure(png.name, problem), table(result, problem))
        rep = result["representative"].get(problem)
        if rep:
            pvd = _write_vtk(rep, out / f"vtk_{problem}")
            page.add(Text(f"Representative run: {rep['series'].label} on {rep['cells']} cells, "
                          f"`{pvd.relative_to(out)}`."))
    page.add(Heading("Findings (reported, not judged)"),
             Items(tuple(f"{f.name}: {f.value:.3f}. {f.sentence}" for f in findings(result)), "(none in this preset)"),
             Heading("Checks"), Checks(checks(result)))
    return write_page(page, out / "convergence.md")


#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings, main_figure=MAIN_FIGURE)
