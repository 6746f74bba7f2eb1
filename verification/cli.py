"""``mpmref verify [CASE ...] [--quick|--full] [--backend B] [--out DIR] [--scheduler ADDRESS] [--workers N]``.

Runs the named verification cases (default: every available case) and writes, under ``DIR``, one folder per
case (its VTK series, PNG plots, tables and ``report.md``) and an index (``report.md``, ``index.html``)
with every check's figure, bound and verdict. Exit code 0 when every check passes, 1 otherwise, 2 for an
unknown case name.
"""

import sys
import time
from pathlib import Path

from mpmref.backends import BACKENDS

from . import registry
from .common import failed
from .executor import Executor
from .report import machine, write_case_report, write_index

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
    p.add_argument("--backend", default="numpy", choices=BACKENDS, help="execution backend (default: numpy)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"report folder (default: {DEFAULT_OUT})")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run sweeps on this dask.distributed scheduler")
    p.add_argument("--workers", type=int, help="local worker processes for sweeps (default: CPU cores)")
    return p


def cmd_verify(args):
    """Run the cases of ``args`` and write the report; returns the exit code."""
    names = args.cases or registry.available()
    unknown = [n for n in names if n not in registry.CASES]
    if unknown:
        print(f"mpmref verify: unknown case(s) {', '.join(unknown)}; available: {', '.join(registry.available())}",
              file=sys.stderr)
        return 2
    executor = Executor(scheduler=args.scheduler, workers=args.workers)
    start, outcomes = time.perf_counter(), []
    for i, name in enumerate(names, 1):
        print(f"[{i}/{len(names)}] {name} ({args.preset}, {args.backend}) ...", flush=True)
        case_dir = args.out / name
        outcome = registry.run_case(name, args.preset, args.backend, executor, out_dir=case_dir)
        write_case_report(outcome, case_dir)
        outcomes.append(outcome)
        _print_outcome(outcome, case_dir)
    meta = {"preset": args.preset, "backend": args.backend, "executor": executor.describe(),
            "wall_s": time.perf_counter() - start, "machine": machine()}
    md, page = write_index(args.out, outcomes, meta)
    total = sum(len(o.checks) for o in outcomes)
    n_failed = sum(len(failed(o.checks)) for o in outcomes)
    errors = sum(o.error is not None for o in outcomes)
    print(f"{total - n_failed} of {total} checks pass, {errors} case(s) stopped with an error, "
          f"{meta['wall_s']:.1f} s; report: {md} and {page}")
    return 0 if all(o.passed for o in outcomes) else 1


def _print_outcome(outcome, case_dir):
    passed = sum(c.passed for c in outcome.checks)
    print(f"    {outcome.verdict}: {passed} of {len(outcome.checks)} checks pass in {outcome.wall_s:.1f} s "
          f"-> {case_dir / 'report.md'}", flush=True)
    for c in outcome.checks:
        if not c.passed:
            print(f"    FAIL {c.name}: {c.value:.6g} (bound {c.relation} {c.bound:.6g})", flush=True)
    if outcome.error is not None:
        print("    " + outcome.error.strip().splitlines()[-1], flush=True)
