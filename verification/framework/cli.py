"""``mpmref verify [CASE ...] [--quick|--full] [--backend B] [--out DIR] [--scheduler A] [--workers N] [--no-progress]``

Runs the named verification cases (default: every available case) and writes, under ``DIR``, one folder per
case (its VTK series, PNG plots, tables and ``report.md``) and an index (``report.md``, ``index.html``, and
``results.json`` for programs) with the findings, then every check's figure, bound and verdict. While it
runs, a line per case on standard error says when the case starts and when it finishes (wall time,
verdict); standard output gets the failing checks and the summary at the end. Exit code 0 when every
check passes, 1 otherwise, 2 for an unknown case name or a backend reference that does not resolve or lacks
a stage every scene needs (checked before any case runs).

``--backend`` takes any backend reference of :mod:`mpmref.backends` (``numpy``, ``numba``, a plugin's name or
``MODULE:ATTRIBUTE``): every simulation of every case runs on it, and the cases that compare two backends take it
as the candidate and the NumPy reference as the truth. The report names it, with its version.
"""

import os
import sys
import time
from pathlib import Path

from mpmref import SceneBuilder
from mpmref.backends import OPTION_HELP, make_backend, reference_argument
from mpmref.cli import add_threads_option, apply_threads

from . import registry, warmup
from .common import failed
from .executor import Executor
from .report import case_record, machine, write_case_report, write_index

DEFAULT_OUT = Path("reports") / "verify"


def add_parser(subparsers):
    """Add the ``verify`` subcommand to an argparse ``subparsers`` object (sets ``func``)."""
    p = subparsers.add_parser("verify", help="run verification cases and write a report",
                              description=__doc__.splitlines()[0])
    p.add_argument("cases", nargs="*", metavar="CASE",
                   help=f"cases to run (default: all available: {', '.join(registry.available())})")
    preset = p.add_mutually_exclusive_group()
    preset.add_argument("--quick", dest="preset", action="store_const", const="quick",
                        help="small, fast preset (the one the tests run)")
    preset.add_argument("--full", dest="preset", action="store_const", const="full",
                        help="the largest preset (long)")
    p.set_defaults(preset="default", func=cmd_verify)
    p.add_argument("--backend", default="numpy", type=reference_argument, metavar="NAME|MODULE:ATTRIBUTE",
                   help=OPTION_HELP + " (default: numpy)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"report folder (default: {DEFAULT_OUT})")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run sweeps on this dask.distributed scheduler")
    p.add_argument("--workers", type=int, help="local worker processes for sweeps (default: CPU cores)")
    add_threads_option(p)
    p.add_argument("--no-progress", action="store_true", help="no per-case progress lines on standard error")
    return p


def cmd_verify(args):
    """Run the cases of ``args`` and write the report; returns the exit code."""
    names = args.cases or registry.available()
    unknown = [n for n in names if n not in registry.CASES]
    if unknown:
        print(f"mpmref verify: unknown case(s) {', '.join(unknown)}; available: {', '.join(registry.available())}",
              file=sys.stderr)
        return 2
    apply_threads(args.threads)
    backend = check_backend(args.backend)
    executor = Executor(scheduler=args.scheduler, workers=args.workers)
    start = time.perf_counter()
    compiling = warmup.start(names, args.preset, args.backend)
    if compiling is not None:
        _progress(args, "compiling the Numba kernels of later cases in a background process (cache: "
                        f"{os.environ.get('NUMBA_CACHE_DIR', 'Numba default')}; delete it to recompile)")
    try:
        records = _run_cases(args, names, executor, compiling)
    finally:
        warmup.stop(compiling)
    meta = {"preset": args.preset, "executor": executor.describe(), "wall_s": time.perf_counter() - start,
            "machine": machine(), "backend": backend}
    md, page, data = write_index(args.out, records, meta)
    for record in records:
        _print_problems(record.outcome)
    outcomes = [r.outcome for r in records]
    total = sum(len(o.checks) for o in outcomes)
    n_failed = sum(len(failed(o.checks)) for o in outcomes)
    errors = sum(o.error is not None for o in outcomes)
    print(f"{total - n_failed} of {total} checks pass, {errors} case(s) stopped with an error, "
          f"{meta['wall_s']:.1f} s; report: {md}, {page} and {data}")
    return 0 if all(o.passed for o in outcomes) else 1


def probe_scene():
    """The smallest scene every backend must run: a 2D elastic block, synchronous, no walls or bodies."""
    return (SceneBuilder(dim=2, name="backend_probe").grid(size=1.0, cells=8)
            .material("solid", type="fixed_corotated", E=1.0e3, nu=0.3, rho=1.0)
            .box("solid", lower=[0.25, 0.25], upper=[0.75, 0.75]).time(dt=1.0e-3, steps=1).build())


def check_backend(reference):
    """The backend ``reference`` described for the report (:func:`mpmref.backends.describe`), once made for the
    :func:`probe_scene` and checked: a backend without the stages every scene needs is refused
    (:class:`~mpmref.errors.BackendError`, exit 2) before any case runs. Stages that only some scenes need
    (asynchronous stepping, rigid bodies) are checked where a case builds such a scene."""
    from mpmref.backends import describe

    return describe(reference, make_backend(reference, probe_scene()))


def _run_cases(args, names, executor, compiling):
    """Run and report each case, with a progress line when it starts and when it ends; the records come
    back in the order of ``names``. The NumPy-only cases run first; a case that runs a compiled backend
    runs between them as soon as the background compilation (:mod:`.warmup`) has compiled every kernel it
    needs (:func:`.warmup.can_start`), or else after the whole compilation, so that no kernel is compiled
    twice."""
    later = [n for n in names if warmup.compiles(n, args.preset, args.backend)]
    first = [n for n in names if n not in later]
    records = {}
    for i in range(1, len(names) + 1):
        early = next((n for n in later if warmup.can_start(compiling, n)), None)
        if early is None and not first:
            warmup.wait(compiling, lambda line: _progress(args, line))
        name = early or (first or later).pop(0)
        if name == early:
            later.remove(name)
        records[name] = _run_case(args, name, f"[{i}/{len(names)}] {name}", executor)
    return [records[n] for n in names]


def _run_case(args, name, tag, executor):
    """Run one case and write its report folder; the case's record."""
    _progress(args, f"{tag}: started ({args.preset} preset, --backend {args.backend})")
    case_dir = args.out / name
    outcome = registry.run_case(name, args.preset, args.backend, executor, out_dir=case_dir)
    record = case_record(outcome, case_dir)
    write_case_report(record, case_dir)
    _progress(args, f"{tag}: finished in {outcome.wall_s:.1f} s, {outcome.verdict} "
                    f"({sum(c.passed for c in outcome.checks)} of {len(outcome.checks)} checks pass, "
                    f"{len(record.findings)} findings; backends run: {', '.join(record.backends)})")
    return record


def _progress(args, line):
    if not args.no_progress:
        print(line, file=sys.stderr, flush=True)


def _print_problems(outcome):
    """The failing checks and the error of one case, on standard output."""
    for c in failed(outcome.checks):
        print(f"{outcome.name}: FAIL {c.name}: {c.value:.6g} (bound {c.relation} {c.bound:.6g})")
    if outcome.error is not None:
        print(f"{outcome.name}: ERROR " + outcome.error.strip().splitlines()[-1] + f" (see {outcome.name}/report.md)")
