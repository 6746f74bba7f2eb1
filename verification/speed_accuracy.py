r"""Speed against accuracy: wall time and error across scheme × kernel × resolution × backend, and the Pareto front.

Set-up: the refinement runs of :mod:`verification.convergence` (the axially vibrating bar; with the full
preset also the manufactured solution), each run by :func:`verification.convergence.run_level`, which
steps the problem to its end time and returns the displacement error :math:`e_u` at :math:`T/4` and the
wall time of the stepping loop.

How the timings are taken (:func:`run`, :func:`timing_conditions`):

* every (problem, scheme, kernel, backend) runs its coarsest level once first, untimed, so that a
  compiled backend's compile or cache-load time is not counted;
* local sweeps run at most one process per CPU core, and Numba runs ``Params.threads`` threads (default
  one) in each, so that no two timed runs share a core; both backends are then timed on one core each.
  On a ``dask.distributed`` cluster the processes per core are not known, and the report says so;
* the load average before and after the sweep is recorded: other work on the machine slows every run.

A run is on the **Pareto front** of its problem when no other run is both faster and more accurate:
those are the only runs worth choosing, whatever the accuracy wanted. Timings are reported, never
asserted (they depend on the machine and its load); the checks concern the errors only:

* **The backends agree on the error.** The backends compute the same trajectory up to round-off, so
  :math:`|e_u^{a} - e_u^{r}| \le \max_p|x^a_p - x^r_p| / U \le n\cdot 10^{-12}\, X / U`, with :math:`n`
  steps, the trajectory bound of :mod:`verification.backends`, :math:`X` the largest coordinate of the
  domain and :math:`U` the displacement amplitude.
* **Resolution does not buy PIC second-order accuracy.** PIC's transfer error is first order in
  :math:`\Delta x` (:func:`verification.convergence.pic_bound_constant`), so on PIC's finest grid its error
  is still larger than that of every second-order scheme on the coarsest grid.

On a backend that implements a part (:mod:`verification.framework.applicable`): a series runs, on the reference and on
the backend, if the backend implements its scene as the convergence case fits it (its material as declared: the
errors are against that material's analytic solution); the others are not applicable.
"""

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .backends import trajectory_bound
from .convergence import ALLOWS, LevelRun, Series, run_level
from .framework.applicable import Triage
from .framework.case import VerificationCase
from .framework.common import Check, Finding
from .framework.executor import Executor
from .framework.page import Checks, Figure, Heading, Items, Page, Table, Text, write_page
from .framework.report import pyplot, save_figure, write_series

#: (scheme, force) pairs the convergence case names
SCHEMES = (("pic", "classic"), ("apic", "classic"), ("mls", "mls"))
#: relative difference below which two errors are the same accuracy (far above backend round-off)
SAME_ERROR = 1e-9


#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "speed_accuracy_bar.png"

@dataclass(frozen=True)
class Params:
    problems: tuple = ("bar",)
    kernels: tuple = ("quadratic", "cubic")
    cells: tuple = (16, 32, 64, 128, 256)
    backends: tuple = ("numpy", "numba")
    cfl: float = 0.4
    ppa: int = 2  # particles per cell per axis
    frames: int = 8  # VTK frames of the representative run (the sweep's most accurate)
    threads: int = 1  # Numba threads in each timing process (one process per core)

    @classmethod
    def quick(cls):
        return cls(kernels=("quadratic",), cells=(16, 32))

    @classmethod
    def full(cls):
        return cls(problems=("bar", "mms"), cells=(16, 32, 64, 128, 256, 512))


def _series(problem, scheme, force, kernel):
    return Series(problem, scheme, force, kernel, expected_rate=1.0 if scheme == "pic" else 2.0)


def numba_threads(backend, threads):
    """A context that runs the enclosed code with ``threads`` Numba threads when ``backend`` is ``"numba"``."""
    from mpmref.backends.numba.threads import on_threads

    return on_threads(threads if backend == "numba" else None)


def compiled_scenes(params, backend="numpy"):
    """``[(backend, scene)]`` this case runs on a compiled backend: each series' coarsest grid (see
    :mod:`verification.framework.warmup`)."""
    compared = ("numpy", backend) if backend != "numpy" else params.backends
    scenes = [(b, Triage(b).fit(b, s.build_problem().scene(params.cells[0], s.method(), params.ppa), ALLOWS))
              for b in compared if b != "numpy" for s in (_series(p, scheme, force, k) for p in params.problems
                                                          for scheme, force in SCHEMES for k in params.kernels)]
    return [(b, scene) for b, scene in scenes if scene is not None]


def run_group(job):
    """One (series, backend) on every grid, after an untimed warm-up on the coarsest."""
    series, backend, cells, cfl, ppa, threads = job
    with numba_threads(backend, threads):
        run_level(LevelRun(series, cells[0], cfl, ppa, backend))
        return [run_level(LevelRun(series, c, cfl, ppa, backend)) for c in cells]


def timing_executor(executor):
    """``executor`` itself on a cluster; locally, the same with at most one process per CPU core."""
    cores = os.cpu_count() or 1
    if executor.scheduler is not None or executor.workers <= cores:
        return executor
    return Executor(workers=cores)


def timing_conditions(executor, jobs, threads):
    """One sentence saying how the timed runs shared the machine (for the report)."""
    cores = os.cpu_count() or 1
    if executor.scheduler is not None:
        return (f"Timed on the dask.distributed cluster {executor.scheduler}: how many runs shared a core there "
                "is not known, so the timings may include contention.")
    processes = min(executor.workers, jobs)
    sharing = "at most one timed run per core" if processes * threads <= cores else "more threads than cores"
    return (f"Timed in {processes} {'process' if processes == 1 else 'processes'} at once on {cores} "
            f"{'core' if cores == 1 else 'cores'}, Numba at {threads} {'thread' if threads == 1 else 'threads'} "
            f"in each: {sharing}; compilation excluded by an untimed warm-up run.")


def position_scale(series, cells, ppa):
    """:math:`X`: the largest coordinate magnitude of the problem's grid."""
    grid = series.build_problem().scene(cells, series.method(), ppa).grid
    return float(np.max(np.abs([grid.origin, grid.origin + np.array(grid.cells) * grid.dx])))


def run(params=Params(), backend="numpy", executor=None):
    """Every problem × scheme × kernel × backend × grid (through ``executor``; default: in this process).

    With ``backend`` other than the reference the backends compared are ``("numpy", backend)``.
    """
    executor = timing_executor(executor or Executor(workers=1))
    backends = params.backends if backend == "numpy" else ("numpy", backend)
    triage = Triage(backend)
    series = [_series(p, s, f, k) for p in params.problems for s, f in SCHEMES for k in params.kernels
              if not (p == "mms" and s == "pic")]
    series = [s for s in series if triage.scene(f"{_label(s)} (its runs and checks)",
                                                s.build_problem().scene(params.cells[0], s.method(), params.ppa),
                                                ALLOWS, run=_label(s))]
    if not series:
        raise triage.nothing_ran()
    jobs = [(s, b, params.cells, params.cfl, params.ppa, params.threads) for s in series for b in backends]
    load_before = os.getloadavg()[0]
    groups = executor.map(run_group, jobs)
    timing = {"conditions": timing_conditions(executor, len(jobs), params.threads),
              "load_before": load_before, "load_after": os.getloadavg()[0]}
    points = []
    for (series, b, *_), levels in zip(jobs, groups):
        for lv in levels:
            lv.pop("frames")
            points.append({"series": series, "backend": b, **lv})
    for problem in params.problems:
        mark_pareto([p for p in points if p["series"].problem == problem])
    best = min((p for p in points if p["series"].problem == params.problems[0]), key=lambda p: p["error_u"])
    frames = run_level(LevelRun(best["series"], best["cells"], params.cfl, params.ppa, best["backend"],
                                params.frames))["frames"]
    return {"params": params, "backends": backends, "points": points, "representative": (best, frames),
            "timing": timing, **triage.record()}


def backends_run(result, backend):
    """The backends whose runs were timed and compared."""
    return result["backends"]


def mark_pareto(points):
    """Set ``pareto`` on each point: true when no faster point is as accurate.

    Errors within the relative :data:`SAME_ERROR` of each other count as equal, so that the backends'
    round-off differences (about 1e-15 on errors of 1e-4) do not put the slower of two identical runs on
    the front.
    """
    best_error = np.inf
    for p in sorted(points, key=lambda p: (p["wall_s"], p["error_u"])):
        p["pareto"] = p["error_u"] < best_error * (1.0 - SAME_ERROR)
        best_error = min(best_error, p["error_u"])


# ------------------------------------------------------------------------------------------ checks
def _label(series):
    return f"{series.problem}: {series.label}"


def checks(result):
    """Backends agree on every error; PIC's finest error exceeds every second-order scheme's coarsest."""
    params, points, out = result["params"], result["points"], []
    ref = {(p["series"], p["cells"]): p["error_u"] for p in points if p["backend"] == "numpy"}
    for p in (p for p in points if p["backend"] != "numpy"):
        s = p["series"]
        bound = trajectory_bound(p["steps"]) * position_scale(s, p["cells"], params.ppa) \
            / s.build_problem().displacement_scale()
        out.append(Check(f"{_label(s)} {p['cells']} cells: |e_u({p['backend']}) - e_u(numpy)|",
                         abs(p["error_u"] - ref[(s, p["cells"])]), "<=", bound,
                         "same trajectory to n·1e-12: n·1e-12·X/U"))
    for problem in params.problems:
        mine = [p for p in points if p["series"].problem == problem]
        pic = [p["error_u"] for p in mine if p["series"].scheme == "pic" and p["cells"] == params.cells[-1]]
        second = [p["error_u"] for p in mine if p["series"].scheme != "pic" and p["cells"] == params.cells[0]]
        if pic and second:
            out.append(Check(f"{problem}: PIC's error on {params.cells[-1]} cells over the worst second-order "
                             f"error on {params.cells[0]} cells", min(pic) / max(second), ">", 1.0,
                             "PIC is first order in Δx, the others second order"))
    return out


def findings(result):
    """NumPy's wall time over each other backend's on the finest grid (median over the series): measured, not judged.

    Timings depend on the machine and its load, so they are findings, never checks.
    """
    params, timing, out = result["params"], result["timing"], []
    for problem in params.problems:
        finest = [p for p in result["points"] if p["series"].problem == problem and p["cells"] == params.cells[-1]]
        reference = {p["series"]: p["wall_s"] for p in finest if p["backend"] == "numpy"}
        for b in (b for b in result["backends"] if b != "numpy"):
            ratio = float(np.median([reference[p["series"]] / p["wall_s"] for p in finest if p["backend"] == b]))
            particles = max(p["particles"] for p in finest)
            out.append(Finding(
                f"{problem}: NumPy wall time / {b} wall time on {params.cells[-1]} cells (median over series)", ratio,
                f"{b} is {'faster' if ratio > 1 else 'slower'} than NumPy here. Runs of at most {particles} particles, "
                f"where fixed per-step costs weigh more than the particle loops. {timing['conditions']} Load "
                f"average {timing['load_before']:.2f} before the sweep, {timing['load_after']:.2f} after."))
    return out


def table(result, problem, front_only=False):
    """The page's table of ``problem``'s runs (those on the Pareto front if ``front_only``), fastest first."""
    header = ("scheme", "kernel", "backend", "cells", "particles", "steps", "wall time [s]", "e_u", "Pareto")
    points = sorted((p for p in result["points"] if p["series"].problem == problem and (p["pareto"] or not front_only)),
                    key=lambda p: p["wall_s"])
    return Table(header, tuple((p["series"].label.split(" ")[0], p["series"].kernel, p["backend"], p["cells"],
                                p["particles"], p["steps"], f"{p['wall_s']:.3g}", f"{p['error_u']:.3e}",
                                "yes" if p["pareto"] else "") for p in points))


# ------------------------------------------------------------------------------------------ figures
def plot(result, problem, path):
    """Error against wall time per (scheme, kernel, backend) with the Pareto front."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 5.5))
    mine = [p for p in result["points"] if p["series"].problem == problem]
    labels = list(dict.fromkeys(p["series"].label for p in mine))
    markers = dict(zip(result["backends"], "os^v"))
    for i, label in enumerate(labels):
        for b in result["backends"]:
            line = sorted((p for p in mine if p["series"].label == label and p["backend"] == b),
                          key=lambda p: p["cells"])
            ax.loglog([p["wall_s"] for p in line], [p["error_u"] for p in line], marker=markers[b], color=f"C{i}",
                      mfc="none" if b != "numpy" else f"C{i}", label=f"{label} ({b})")
    front = sorted((p for p in mine if p["pareto"]), key=lambda p: p["wall_s"])
    ax.step([p["wall_s"] for p in front], [p["error_u"] for p in front], "k--", where="post", label="Pareto front")
    ax.set(xlabel="wall time of the run [s]", ylabel="displacement error e_u", title=f"{problem}: speed vs accuracy")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return save_figure(fig, path, caption=(
        f"{problem}: displacement error against wall time, one line per scheme, kernel and backend (filled: NumPy, "
        "hollow: the others), refining to the right; the dashed staircase is the Pareto front. Look for the runs "
        "on the front (the only ones worth choosing) and for each backend pair lying at the same height (same "
        f"error, checked); their horizontal offset is the speed-up. {result['timing']['conditions']}"))


def report(result, out_dir):
    """Write one plot per problem, the representative run's VTK series and ``speed_accuracy.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    best, frames = result["representative"]
    vtk = [(f["time"], f["x"], {"id": f["id"], "velocity": f["velocity"], "displacement": f["displacement"],
                                "displacement_error": f["displacement"] - f["displacement_exact"]}) for f in frames]
    paths = [write_series(out / "vtk" / "most_accurate", vtk)]
    timing = result["timing"]
    page = Page("Speed against accuracy", [Text(
        f"Backends {', '.join(result['backends'])}. {timing['conditions']} Load average {timing['load_before']:.2f} "
        f"before the sweep, {timing['load_after']:.2f} after. Representative run (the most accurate): "
        f"{best['series'].label}, {best['backend']}, {best['cells']} cells (`vtk/most_accurate`).")])
    for problem in result["params"].problems:
        paths.append(plot(result, problem, out / f"speed_accuracy_{problem}.png"))
        page.add(Heading(problem), Figure(f"speed_accuracy_{problem}.png", problem), Text("Pareto front:"),
                 table(result, problem, front_only=True), Text("Every run:"), table(result, problem))
    page.add(Heading("Findings (measured, not judged)"),
             Items(tuple(f"{f.name}: {f.value:.3g}. {f.sentence}" for f in findings(result)), "(none: one backend)"),
             Heading("Checks"), Checks(checks(result)))
    return paths + [write_page(page, out / "speed_accuracy.md")]


#: this case, for the registry; it times its runs, so ``mpmref verify`` starts it only after the background
#: compilation has ended (:mod:`verification.framework.warmup`): no compilation shares the machine with the timed runs
CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings, backends_run=backends_run,
                        compiled_scenes=compiled_scenes, main_figure=MAIN_FIGURE, runs_alone=True)
