"""``mpmref study SCENE.toml --vary KEY=VALUES [--vary ...] [--t-end T] [--measure MODULE:FUNCTION]``
``[--exact MODULE:FUNCTION] [--setup MODULE:FUNCTION] [--frames] [--backend B] [--out DIR] [--overwrite]``
``[--scheduler A] [--workers N] [--no-ledger] [--no-progress]``

Runs the scene once for every combination of the varied values (several ``--vary`` give their product; keys
joined by ``:`` vary together), each to the same end time, and writes into ``DIR`` (default
``reports/study/<scene name>``) ``results.json``, ``results.csv``, the plots and ``index.html``: each run's drifts
of energy, momentum, angular momentum and mass, its energy ledger, steps, wall time and the user's measures, and
for every resolution varied (cells, Δt, CFL number, particles per cell) the observed order of each measure.
Every run's scene is validated before any run starts, and varied values whose runs would compute the same numbers
(``method.scheme=apic,mls``: the APIC transfer with the MLS force, both) are named on standard error. A progress
bar on standard error counts the runs; standard output gets the orders and the files at the end. A study run again
reuses the runs whose results are in ``DIR`` (``--overwrite`` runs them again).

Exit status: 0 when every run finished; 1 when a run failed (the others are reported); 2 for a bad scene, key,
value, reference or option (before any run); 130 when interrupted (the finished runs are kept).
"""

import contextlib
import math
import shlex
import sys
import warnings
from pathlib import Path

from mpmref.backends import OPTION_HELP, importable_from_here, reference_argument
from mpmref.cli import (
    OptionError,
    add_threads_option,
    apply_threads,
    compiling,
    end_time_option,
    length_line,
    option_value,
    run_length,
)
from mpmref.errors import ArgumentError

from ..framework.executor import Executor
from . import Interrupted, SameComputationWarning, run_study
from .orders import orders_text, series_label
from .runs import load
from .variations import SYNTAX, label, parse_vary

INTERRUPTED = 130


def _function(option):
    """The argparse ``type`` of ``option``: a ``MODULE:FUNCTION`` reference that resolves here (the current folder
    is importable); the reference itself is kept, to be resolved again in each worker."""
    def check(text):
        importable_from_here()
        load(text, option)
        return text

    return option_value(str, check, "a reference", problem="does not name a function")


def _workers(value):
    if value < 1:
        raise ArgumentError("--workers", value, "an integer >= 1")
    return value


def add_parser(subparsers):
    """Add the ``study`` subcommand to an argparse ``subparsers`` object (sets ``func``)."""
    p = subparsers.add_parser("study", help="convergence and conservation study of a scene file",
                              description=__doc__.split("\n\n")[1])
    p.add_argument("scene", type=Path, help="scene TOML file")
    p.add_argument("--vary", action="append", default=[], metavar="KEY=V1,V2,...",
                   type=option_value(str, parse_vary, "a variation", problem="is not a variation"),
                   help=f"a scene key and its values ({SYNTAX}); several --vary give their product")
    p.add_argument("--t-end", type=end_time_option, metavar="T",
                   help="every run's end time (default: the scene's time.t_end)")
    p.add_argument("--measure", action="append", default=[], type=_function("--measure"), metavar="MODULE:FUNCTION",
                   help="a function f(sim) -> {name: value} measured on each finished run (repeatable)")
    p.add_argument("--exact", type=_function("--exact"), metavar="MODULE:FUNCTION",
                   help="f(scene, t) -> {name: value}: exact values of measures; orders are then errors against them")
    p.add_argument("--setup", type=_function("--setup"), metavar="MODULE:FUNCTION",
                   help="f(sim) called on each new simulation before its first step (fields a scene cannot declare)")
    p.add_argument("--frames", action="store_true", help="write each run's VTK series into DIR/frames/<run id>/")
    p.add_argument("--backend", default="numpy", type=reference_argument, metavar="NAME|MODULE:ATTRIBUTE",
                   help=OPTION_HELP + " (default: numpy)")
    p.add_argument("--out", type=Path, metavar="DIR", help="report folder (default: reports/study/<scene name>)")
    p.add_argument("--overwrite", action="store_true",
                   help="run again the runs whose results an earlier study left in DIR (by default they are reused)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run the runs on this dask.distributed scheduler")
    p.add_argument("--workers", type=option_value(int, _workers, "an integer"), metavar="N",
                   help="local worker processes (default: CPU cores; 1 runs in this process)")
    add_threads_option(p)
    p.add_argument("--no-ledger", action="store_true",
                   help="do not book the energy ledger (it about doubles a NumPy run's time)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on standard error")
    p.set_defaults(func=cmd_study)
    return p


def cmd_study(args):
    """Run the study of ``args`` and write its report; returns the exit code."""
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        raise OptionError(f"--out {args.out}: this is an existing file; name a folder")
    apply_threads(args.threads)
    bar = _ProgressBar(not args.no_progress)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", SameComputationWarning)
            warnings.showwarning = _one_line(warnings.showwarning)
            executor = Executor(scheduler=args.scheduler, workers=args.workers)
            study = run_study(args.scene, args.vary, args.t_end, backend=args.backend, out=args.out,
                              measures=args.measure, exact=args.exact, setup=args.setup, frames=args.frames,
                              overwrite=args.overwrite, ledger=not args.no_ledger, executor=executor,
                              progress=bar.update, announce=lambda runs: _announce_length(runs, executor))
    except KeyboardInterrupt as stop:
        print(f"mpmref study: {interrupted(stop, args.argv)}", file=sys.stderr)
        return INTERRUPTED
    finally:
        bar.close()
    print(summary(study))
    return 1 if any(r["error"] for r in study["runs"]) else 0


def _announce_length(runs, executor):
    """Print the estimated length of the study's ``runs`` on ``executor`` on standard error: each run's
    (:func:`mpmref.cli.run_length`, the scene as declared: a ``--setup`` function is not called), the local workers
    taking them side by side (a Dask cluster's are counted as one)."""
    if not runs:
        return
    with compiling("mpmref study") if _compiles(runs[0]) else contextlib.nullcontext():
        lengths = [n for n in (run_length(r["scene"], r["spec"].backend, r["spec"].t_end) for r in runs)
                   if n is not None]
    if not lengths:
        return
    side_by_side = 1 if executor.scheduler is not None else min(executor.workers, len(lengths))
    seconds = sum(n.seconds for n in lengths)
    work = sum(n.steps * n.particles for n in lengths)
    how = (f"{len(lengths)} runs, {work:.3g} particle-steps at {work / seconds:.3g} particle-steps/s measured on "
           f"each run's first steps here, {side_by_side} at a time")
    wall = max(max(n.seconds for n in lengths), seconds / side_by_side)
    print(length_line("mpmref study", wall, how, "Ctrl-C stops it and keeps the finished runs, which the same "
                      "command reuses"), file=sys.stderr)


def _compiles(run):
    """Whether the backend of ``run`` compiles kernels for its scene (the probe of the runs' length compiles them
    first, here)."""
    from mpmref import Simulation

    try:
        return Simulation(run["scene"], backend=run["spec"].backend).compiles
    except Exception:  # the probe and the run report it
        return False


def interrupted(stop, argv):
    """The line that says what an interrupted study keeps and the command that goes on with it: the same command,
    without ``--overwrite``, which would run the finished runs again."""
    again = shlex.join(["mpmref", *(word for word in argv if word != "--overwrite")])
    if not isinstance(stop, Interrupted):  # while planning, or writing the report
        return f"interrupted outside the runs; the same command reuses the runs that finished: {again}"
    return (f"interrupted; {stop.finished} of {stop.total} runs finished (their results are in {stop.out / 'runs'}); "
            f"the same command reuses them and runs the other {stop.total - stop.finished}: {again}")


def _one_line(show):
    """``warnings.showwarning`` that prints a study's warning as one line on standard error, others by ``show``."""
    def shown(message, category, *args, **kwargs):
        if issubclass(category, SameComputationWarning):
            print(f"mpmref study: warning: {message}", file=sys.stderr)
        else:
            show(message, category, *args, **kwargs)

    return shown


def summary(study):
    """The lines printed at the end: runs, failures, orders, files."""
    runs = study["runs"]
    failed = [r for r in runs if r["error"]]
    backend = study["backend"]
    execution = f", {backend['execution']}" if backend.get("execution") else ""
    lines = [f"{len(runs) - len(failed)} of {len(runs)} runs finished ({sum(r['reused'] for r in runs)} reused from "
             f"an earlier study), {study['wall_s']:.1f} s; backend {backend['backend']}{execution}"]
    lines += [f"FAILED {label(r['params'])}: {r['error'].strip().splitlines()[-1]}" for r in failed]
    for row in study["orders"]:
        if math.isfinite(row["order"]) or math.isfinite(row["richardson"]):
            lines.append(f"order of {row['measure']} in {row['key']} ({series_label(row)}, against "
                         f"{row['against']}): {orders_text(row)}")
    return "\n".join(lines + ["report: " + ", ".join(study["paths"])])


class _ProgressBar:
    """A tqdm bar over the runs on standard error, made when the number of runs to do is known."""

    def __init__(self, enabled):
        self.enabled, self.bar = enabled, None

    def update(self, done, total, run):
        from tqdm import tqdm

        if self.bar is None:
            self.bar = tqdm(total=total, disable=not self.enabled, unit="run", file=sys.stderr, dynamic_ncols=True)
        self.bar.update(done - self.bar.n)
        if run is not None:
            self.bar.set_postfix_str(run, refresh=True)

    def close(self):
        if self.bar is not None:
            self.bar.close()
