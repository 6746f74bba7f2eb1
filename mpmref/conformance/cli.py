"""``mpmref conformance export DIR`` and ``mpmref conformance check --backend NAME|MODULE:ATTRIBUTE``.

Exit status of ``check``: 0 every case passed, 1 a case failed, 2 a backend reference that does not resolve.
"""

from pathlib import Path

from ..backends import OPTION_HELP, reference_argument
from ..cli import add_threads_option, apply_threads
from .cases import DEFAULT_RTOL, MATERIALS, make_cases
from .report import check
from .stages import ALL_CONFORMANCE_STAGES
from .vectors import export


def _add_selection(parser):
    parser.add_argument("--dim", type=int, nargs="+", choices=(2, 3), default=[2, 3],
                        help="dimensions of the cases (default: 2 3)")
    parser.add_argument("--stage", nargs="+", choices=ALL_CONFORMANCE_STAGES, default=list(ALL_CONFORMANCE_STAGES),
                        help="stages to include (default: all; the CPIC stages have 2D float64 cases only)")
    parser.add_argument("--dtype", choices=tuple(DEFAULT_RTOL), default="float64",
                        help="floating-point type of the states (default: float64)")
    parser.add_argument("--material", nargs="+", choices=tuple(MATERIALS), metavar="TYPE",
                        help="only the cases whose materials are all among these types (and the grid update's), "
                        f"for a code with only some constitutive models; types: {', '.join(MATERIALS)}")


def _selected_cases(args):
    return make_cases(dims=tuple(args.dim), stages=tuple(args.stage), dtype=args.dtype, materials=args.material)


def cmd_export(args):
    """Write the selected cases as ``.npz`` files and ``manifest.json`` into ``args.dir``."""
    cases = _selected_cases(args)
    manifest = export(args.dir, cases)
    print(f"wrote {len(cases)} cases to {args.dir} (index: {manifest.name})")
    return 0


def cmd_check(args):
    """Check a backend against the reference (progress bar on standard error unless ``--no-progress``); print
    the table on standard output; exit status 0 if every case passed, else 1."""
    apply_threads(args.threads)
    report = check(args.backend, _selected_cases(args), rtol=args.rtol, progress=not args.no_progress)
    print(report.table(verbose=args.verbose))
    return 0 if report.passed else 1


def add_parser(subparsers):
    """Add the ``conformance`` command with its ``export`` and ``check`` subcommands to ``subparsers``."""
    parser = subparsers.add_parser("conformance", help="check a backend stage by stage against the NumPy "
                                   "reference, or export the test vectors for code in another language")
    actions = parser.add_subparsers(dest="conformance_command", required=True)
    export_parser = actions.add_parser("export", help="write one .npz per case and stage plus manifest.json")
    export_parser.add_argument("dir", type=Path, help="output folder (created if missing)")
    _add_selection(export_parser)
    export_parser.set_defaults(func=cmd_export)
    check_parser = actions.add_parser("check", help="run a backend on every case and print the error table")
    check_parser.add_argument("--backend", required=True, type=reference_argument, metavar="NAME|MODULE:ATTRIBUTE",
                              help="the backend to check: " + OPTION_HELP + "; a factory may return an object "
                              "with only some stages, or a dict {stage: callable}, and the others are skipped")
    check_parser.add_argument("--rtol", type=float, default=None,
                              help="pass threshold on the relative error (default: "
                              + ", ".join(f"{r:g} in {t}" for t, r in DEFAULT_RTOL.items()) + ")")
    check_parser.add_argument("--verbose", action="store_true", help="list every case, not only the failed ones")
    add_threads_option(check_parser)
    check_parser.add_argument("--no-progress", action="store_true",
                              help="no progress bar (it goes to standard error; the table to standard output)")
    _add_selection(check_parser)
    check_parser.set_defaults(func=cmd_check)
    return parser
