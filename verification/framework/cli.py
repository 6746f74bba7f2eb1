"""``mpmref verify [CASE ...] [--scene SCENE.toml] [--quick|--full] [--backend B] [--out DIR] [--scheduler A]
[--workers N] [--no-progress]``

Runs the named verification cases (default: every available case) and writes, under ``DIR``, one folder per
case (its VTK series, PNG plots, tables and ``report.md``) and an index (``report.md``, ``index.html``, and
``results.json`` for programs) with the findings, then every check's figure, bound and verdict. While it
runs, a line per case on standard error says when the case starts and when it finishes (wall time,
verdict); standard output gets the failing checks, each case that stopped with an error (with the scene and the
backend's stage where it was raised) and the summary at the end. Exit code 0 when every check that ran passes,
1 when one fails, a case stops with an error or no check applies at all, 2 for an unknown case name, a bad scene
or option, or a backend reference that does not resolve or lacks a stage every scene needs (checked before any
case runs).

``--backend`` takes any backend reference of :mod:`mpmref.backends` (``numpy``, ``numba``, a plugin's name or
``MODULE:ATTRIBUTE``): every simulation of every case runs on it, and the cases that compare two backends take it
as the candidate and the NumPy reference as the truth. The report names it, with its version. Each case runs on what
the backend implements (:mod:`~verification.framework.applicable`): what it cannot do is listed as *not applicable*,
with the reasons, and counted apart from the checks.

``--scene SCENE.toml`` runs, instead of the cases, the checks of :mod:`verification.scene` on the user's own scene
(momentum, the energy ledger, the backend against the reference, stability at the extremes of CFL), shortened by the
preset; a scene the backend does not implement is refused before any work (exit 2).
"""

import contextlib
import json
import os
import shlex
import sys
import time
from pathlib import Path

from mpmref import SceneBuilder
from mpmref.backends import OPTION_HELP, make_backend, reference_argument
from mpmref.cli import INTERRUPTED, add_threads_option, apply_threads

from . import registry, warmup
from .applicable import ANYTHING, Inapplicable, declaration_of, fit, unmodelable
from .common import failed, summary_sentence, verdict_word
from .coverage import not_exercised
from .executor import Executor
from .report import case_record, machine, write_case_report, write_index

DEFAULT_OUT = Path("reports") / "verify"


def add_parser(subparsers):
    """Add the ``verify`` subcommand to an argparse ``subparsers`` object (sets ``func``)."""
    p = subparsers.add_parser("verify", help="run verification cases and write a report",
                              description=__doc__.splitlines()[0])
    p.add_argument("cases", nargs="*", metavar="CASE",
                   help=f"cases to run (default: all available: {', '.join(registry.available())})")
    p.add_argument("--scene", type=Path, metavar="SCENE.toml",
                   help="check your own scene instead of the cases: momentum, energy ledger, the backend against "
                        "the reference, stability at the extremes of CFL (docs/verification.md)")
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
    """Run the cases of ``args`` (or the checks of its ``--scene``) and write the report; returns the exit code."""
    if args.scene is not None:
        return cmd_verify_scene(args)
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
    with kernel_builds(args):
        compiling = warmup.start(names, args.preset, args.backend)
        if compiling is not None:
            _progress(args, "compiling the Numba kernels of later cases in a background process (cache: "
                            f"{os.environ.get('NUMBA_CACHE_DIR', 'Numba default')}; delete it to recompile)")
        records = {}
        try:
            _run_cases(args, names, executor, compiling, records)
        except KeyboardInterrupt:
            return interrupted(args, names, records)
        finally:
            warmup.stop(compiling)
        meta = {"preset": args.preset, "executor": executor.describe(), "wall_s": time.perf_counter() - start,
                "machine": machine(), "backend": backend}
    return finish(args, [records[n] for n in names], meta)


def kernel_builds(args):
    """The Numba kernels' builds the cases run: the serial builds in the quick preset unless ``--threads`` asks for
    more than one thread or the environment chose a mode (:mod:`mpmref.backends.numba.twin`), here and in the
    processes verify starts; else the mode in force. A serial build compiles in about 60 % of the time of a parallel
    one and gives its bits (tests/test_numba_backend.py), and the quick preset's scenes are small, so that a cold
    ``verify --quick`` spends less of its time compiling; the report says which builds ran (``machine``)."""
    from mpmref.backends.numba import twin

    threads = args.threads is not None and args.threads > 1
    if args.preset != "quick" or threads or os.environ.get(twin.BUILDS_VARIABLE):
        return contextlib.nullcontext()
    return twin.builds_everywhere("serial")


def cmd_verify_scene(args):
    """``mpmref verify --scene``: the checks of :mod:`verification.scene` on the user's scene, after the scene and the
    backend are checked (exit 2 before any work: a bad scene, a case named beside it, a backend that does not
    implement the scene)."""
    from mpmref.backends import describe
    from mpmref.cli import OptionError

    from .. import scene as scene_checks

    if args.cases:
        raise OptionError(f"--scene runs its own checks ({', '.join(scene_checks.CHECKS)}); give no CASE "
                          f"(got {' '.join(args.cases)})")
    params = scene_checks.Params.of(args.scene, args.preset)
    declared = scene_checks.as_run(scene_checks.load(params))  # SceneError: exit 2
    apply_threads(args.threads)
    backend = describe(args.backend, make_backend(args.backend, declared))  # NotImplementedByBackend: exit 2
    executor = Executor(scheduler=args.scheduler, workers=args.workers)
    start = time.perf_counter()
    names, records = list(scene_checks.CHECKS), {}
    try:
        for i, name in enumerate(names, 1):
            records[name] = _run_case(args, name, f"[{i}/{len(names)}] {name}", executor, params=params,
                                      case=scene_checks.case(name))
    except KeyboardInterrupt:
        return interrupted(args, names, records)
    meta = {"preset": args.preset, "executor": executor.describe(), "wall_s": time.perf_counter() - start,
            "machine": machine(), "backend": backend, "scene": str(args.scene)}
    status = finish(args, list(records.values()), meta)
    say_coverage(records.get("reference"))
    return status


def say_coverage(record):
    """Beside ``--scene``'s verdict, what the states its comparison along the scene's run exercised
    (:mod:`~verification.framework.coverage`), one line; and a warning naming what they did not, whose errors these
    checks could not see."""
    result = None if record is None else record.outcome.result
    items = (result or {}).get("exercised", ())
    if not items:
        return
    done = [f"{i.name} ({i.figure:.3g})" for i in items if i.exercised]
    print(f"exercised along the compared runs: {', '.join(done) or 'none of the fields and features checked'}")
    missing = not_exercised(items)
    if missing:
        print(f"mpmref verify: warning: along the compared runs {missing}: a code wrong there passes these checks "
              "(the reference check's findings give the figures; a scene that exercises them, or mpmref conformance "
              "check --scene, compares them)", file=sys.stderr)


def interrupted(args, names, records):
    """Say in one line, after Ctrl-C stopped the cases (their workers ended, :mod:`.executor`), what is kept and what
    running the command again does; the exit status 130."""
    kept = f" ({', '.join(records)}: reports in {args.out}/<case>/)" if records else ""
    print(f"mpmref verify: interrupted; {len(records)} of {len(names)} cases finished{kept}; the index was not "
          f"written; the same command runs every case again: {shlex.join(['mpmref', *args.argv])}", file=sys.stderr)
    return INTERRUPTED


def finish(args, records, meta):
    """Write the index, print the failures, the errors and the summary line; the exit status: 0 when every check that
    ran passes and at least one ran, 1 otherwise (a failing check, a case stopped with an error, or nothing checked)."""
    md, page, data = write_index(args.out, records, meta)
    for record in records:
        _print_problems(record.outcome)
    summary = json.loads(data.read_text())["summary"]
    print(f"{summary_sentence(summary)}; {meta['wall_s']:.1f} s; report: {md}, {page} and {data}")
    if not summary["checks"]:
        print("mpmref verify: no check applies to this backend: nothing was verified", file=sys.stderr)
    return 0 if verdict_word(summary) == "PASS" else 1


def probe_scene(dim=2):
    """The smallest scene every backend must run: an elastic block, synchronous, no walls or bodies."""
    return (SceneBuilder(dim=dim, name="backend_probe").grid(size=1.0, cells=8)
            .material("solid", type="fixed_corotated", E=1.0e3, nu=0.3, rho=1.0)
            .box("solid", lower=[0.25] * dim, upper=[0.75] * dim).time(dt=1.0e-3, steps=1).build())


#: what the probe may change to fit a backend that implements a part (:mod:`.applicable`): anything, since it only
#: has to make the backend's stages run
PROBE_ALLOWS = ANYTHING


def check_backend(reference):
    """The backend ``reference`` described for the report (:func:`mpmref.backends.describe`), once made for the
    :func:`probe_scene` fitted to what it implements (:func:`.applicable.fit`, every axis free: the 3D slab for a
    code without 2D, its own scheme, kernel and material) and checked: a backend without the stages every scene needs
    is refused (:class:`~mpmref.errors.BackendError`, exit 2) before any case runs, and so is one that implements no
    probe at all, or whose declaration mpmref cannot model (one line naming what mpmref lacks,
    :func:`.applicable.unmodelable`); where it can model a part of it, that line is a warning and the cases run on
    the rest. Stages that only some scenes need (asynchronous stepping, rigid bodies) are checked where a case builds
    such a scene."""
    from mpmref.backends import describe
    from mpmref.errors import BackendError, NotImplementedByBackend

    lacking = unmodelable(declaration_of(reference))
    try:
        scene = fit(probe_scene(), reference, PROBE_ALLOWS).scene
    except Inapplicable as exc:
        if lacking:
            raise BackendError(f"backend {reference!r} declares what mpmref cannot model: {'; '.join(lacking)}: no "
                               "check of P2G, G2P or a step can run on it") from None
        raise NotImplementedByBackend(reference, "backend_probe", list(exc.reasons)) from None
    for line in lacking:
        print(f"mpmref verify: warning: {line}; the checks run on what mpmref can model", file=sys.stderr)
    return describe(reference, make_backend(reference, scene))


def _run_cases(args, names, executor, compiling, records):
    """Run and report each case, with a progress line when it starts and when it ends, its record put in ``records``
    under its name as it finishes. The NumPy-only cases run first; a case that runs a compiled backend
    runs between them as soon as the background compilation (:mod:`.warmup`) has compiled every kernel it
    needs (:func:`.warmup.can_start`), or else after the whole compilation, so that no kernel is compiled
    twice."""
    later = [n for n in names if warmup.compiles(n, args.preset, args.backend)]
    first = [n for n in names if n not in later]
    for i in range(1, len(names) + 1):
        early = next((n for n in later if warmup.can_start(compiling, n)), None)
        if early is None and not first:
            warmup.wait(compiling, lambda line: _progress(args, line))
        name = early or (first or later).pop(0)
        if name == early:
            later.remove(name)
        records[name] = _run_case(args, name, f"[{i}/{len(names)}] {name}", executor)


def _run_case(args, name, tag, executor, params=None, case=None):
    """Run one case (a check of ``--scene``: its ``case`` and ``params``) and write its report folder; the case's
    record."""
    _progress(args, f"{tag}: started ({args.preset} preset, --backend {args.backend})")
    case_dir = args.out / name
    outcome = registry.run_case(name, args.preset, args.backend, executor, out_dir=case_dir, params=params,
                                case=case)
    record = case_record(outcome, case_dir)
    write_case_report(record, case_dir)
    _progress(args, f"{tag}: finished in {outcome.wall_s:.1f} s, {outcome.verdict} "
                    f"({sum(c.passed for c in outcome.checks)} of {len(outcome.checks)} checks pass, "
                    f"{len(outcome.not_applicable)} not applicable, {len(record.findings)} findings; backends run: "
                    f"{', '.join(record.backends)})")
    return record


def _progress(args, line):
    if not args.no_progress:
        print(line, file=sys.stderr, flush=True)


def _print_problems(outcome):
    """The failing checks and the error of one case (the scene and stage it was raised in), on standard output."""
    for c in failed(outcome.checks):
        print(f"{outcome.name}: FAIL {c.name}: {c.value:.6g} (bound {c.relation} {c.bound:.6g})")
    if outcome.error is not None:
        line = outcome.error_line or outcome.error.strip().splitlines()[-1]
        print(f"{outcome.name}: ERROR in {line} (see {outcome.name}/report.md)")
