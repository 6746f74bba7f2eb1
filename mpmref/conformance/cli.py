"""``mpmref conformance export DIR``, ``mpmref conformance check --backend NAME|MODULE:ATTRIBUTE`` and ``mpmref
conformance search --backend ...``, on the built-in catalogue, on cases drawn from a scene (``--scene SCENE.toml``),
or (``check``, ``export``) on saved case files (``--case FILE``); ``check --results DIR`` judges the outputs that code
in another language computed from the exported vectors (:mod:`~mpmref.conformance.results`).

Exit status of ``check``: 0 every case that applies passed (at least one), 1 a case failed or none applied, 2 a bad
option, scene or backend reference. Of ``search``: 0 nothing found, 1 a disagreement found (and saved), 2 the same.
"""

import math
from pathlib import Path

from ..backends import OPTION_HELP, reference_argument, resolve
from ..cli import OptionError, add_threads_option, apply_threads, option_value
from ..errors import ArgumentError
from ..physics.kernels import KERNELS
from ..scene import SCHEMES
from .candidates import candidate_implements
from .casefile import load_case
from .cases import DEFAULT_RTOL, MATERIALS, base_seed, make_cases
from .coverage import coverage_lines
from .report import check, relative_tolerance
from .results import ResultsError, check_results, read_declaration
from .scenes import scene_cases, scene_record
from .search import DEFAULT_BUDGET, SEARCH_STAGES, search
from .stages import ALL_CONFORMANCE_STAGES
from .vectors import export

#: the options that select catalogue cases, which a scene fixes itself
CATALOGUE_OPTIONS = ("dim", "material", "scheme", "kernel")


def _add_selection(parser):
    parser.add_argument("--scene", type=Path, metavar="SCENE.toml",
                        help="draw every case from this scene: its dimension, method, materials and their "
                        "parameters, walls, colliders, gravity and dtype, at its scales (docs/conformance.md, "
                        "'Cases from your scene'); without it, the built-in catalogue")
    parser.add_argument("--dim", type=int, nargs="+", choices=(2, 3),
                        help="dimensions of the catalogue's cases (default: 2 3)")
    parser.add_argument("--stage", nargs="+", choices=ALL_CONFORMANCE_STAGES,
                        help="stages to include (default: all; with --scene, every stage its steps call; the CPIC "
                        "stages have float64 cases only)")
    parser.add_argument("--dtype", choices=tuple(DEFAULT_RTOL),
                        help="floating-point type of the states (default: float64, or the scene's)")
    parser.add_argument("--material", nargs="+", choices=tuple(MATERIALS), metavar="TYPE",
                        help="only these material types: the per-method cases run on them, and the cases with other "
                        f"materials are left out; types: {', '.join(MATERIALS)}")
    parser.add_argument("--scheme", nargs="+", choices=SCHEMES, metavar="SCHEME",
                        help="only the cases of these schemes where the stage depends on the scheme (the others run "
                        f"on one of them); schemes: {', '.join(SCHEMES)}")
    parser.add_argument("--kernel", nargs="+", choices=tuple(KERNELS), metavar="KERNEL",
                        help="only the cases of these kernels where the stage depends on the kernel; kernels: "
                        f"{', '.join(KERNELS)}")
    parser.add_argument("--seed", type=option_value(int, base_seed, "an integer"), default=0,
                        help="base seed of the draws, an integer >= 0 (default 0: the same cases on every machine); "
                        "another gives every case a new grid, time step, time and state")
    parser.add_argument("--case", nargs="+", type=Path, metavar="FILE",
                        help="only these saved cases (the .npz files conformance search writes), instead of the "
                        "catalogue or a scene")


def _refuse_with(args, option, others):
    """:class:`~mpmref.cli.OptionError` naming the options of ``others`` given together with ``option``."""
    given = [f"--{name}" for name in others if getattr(args, name, None) is not None]
    if given:
        raise OptionError(f"{', '.join(given)}: not with --{option} (the {option} sets them)")


def _selected_cases(args, implements=None):
    """The cases the options select: the saved ``--case`` files, drawn from ``--scene``, or the catalogue fitted to
    ``implements``."""
    if args.case is not None:
        _refuse_with(args, "case", ("scene", *CATALOGUE_OPTIONS, "stage", "dtype"))
        try:
            return [load_case(path) for path in args.case]
        except (OSError, ValueError) as exc:
            raise OptionError(f"--case: {exc}") from None
    if args.scene is not None:
        _refuse_with(args, "scene", CATALOGUE_OPTIONS)
        try:
            return scene_cases(args.scene, stages=args.stage, dtype=args.dtype, seed=args.seed)
        except ValueError as exc:
            raise OptionError(f"--stage: {exc}") from None
    return make_cases(dims=tuple(args.dim or (2, 3)), stages=tuple(args.stage or ALL_CONFORMANCE_STAGES),
                      dtype=args.dtype or "float64", materials=args.material, implements=implements,
                      schemes=args.scheme, kernels=args.kernel, seed=args.seed)


def _probes(args):
    """The cases a candidate's declaration is probed on: the saved cases, the scene's stress cases, or the
    catalogue's."""
    if args.case is not None:
        return _selected_cases(args)
    return make_cases(stages=("stress",)) if args.scene is None else scene_cases(args.scene, stages=("stress",))


def _declared(path):
    """The :class:`~mpmref.backends.capabilities.Implements` of a declaration file or results folder (``None`` for
    ``None``); a wrong file is an :class:`~mpmref.cli.OptionError` naming it."""
    if path is None:
        return None
    try:
        return read_declaration(path).implements
    except ResultsError as exc:
        raise OptionError(str(exc)) from None


def cmd_export(args):
    """Write the selected cases as ``.npz`` files and ``manifest.json`` into ``args.dir`` (the catalogue fitted to
    ``--implements``, as ``check`` fits it to a backend)."""
    cases = _selected_cases(args, _declared(args.implements))
    manifest = export(args.dir, cases, scene=None if args.scene is None else scene_record(args.scene))
    print(f"wrote {len(cases)} cases to {args.dir} (index: {manifest.name})")
    return 0


def cmd_check(args):
    """Check a backend against the reference (progress bar on standard error unless ``--no-progress``); print
    the table and what it compared (:func:`.coverage.coverage_lines`) on standard output; exit status 0 if every
    case that applies passed, else 1."""
    if args.results is not None:
        return _check_results(args)
    apply_threads(args.threads)
    found = resolve(args.backend)
    implements = candidate_implements(found, (c.scene() for c in _probes(args)))
    report = check(args.backend, _selected_cases(args, implements), rtol=args.rtol, progress=not args.no_progress,
                   implements=implements)
    print(report.table(verbose=args.verbose))
    for line in coverage_lines(report):
        print(line)
    return 0 if report.passed else 1


def _check_results(args):
    """``check --results DIR``: the outputs in ``DIR`` judged on the selected cases (the catalogue fitted to the
    folder's ``implements.json``), with the table a backend gets."""
    try:
        report = check_results(args.results, _selected_cases(args, _declared(args.results)), rtol=args.rtol,
                               progress=not args.no_progress)
    except ResultsError as exc:
        raise OptionError(str(exc)) from None
    print(report.table(verbose=args.verbose))
    for line in coverage_lines(report):
        print(line)
    return 0 if report.passed else 1


def cmd_search(args):
    """Search for states where a backend and the reference disagree (:mod:`.search`); print what was found, saved
    under ``--out``, or how many states were tried; exit status 1 if a disagreement was found, else 0."""
    apply_threads(args.threads)
    try:
        budget = None if args.time is not None else args.budget
        report = search(args.backend, scene=args.scene, stages=args.stage, budget=budget, seconds=args.time,
                        seed=args.seed, out_dir=args.out, rtol=args.rtol, progress=not args.no_progress)
    except ImportError as exc:
        raise OptionError(f"conformance search needs hypothesis ({exc}): pip install -e '.[test]'") from None
    print(report.text(args.backend))
    return 1 if report.found else 0


def _add_check_options(parser, verb, results=False):
    """``--backend``, ``--rtol``, ``--threads`` and ``--no-progress`` of ``check`` and ``search``; with ``results``,
    ``--results DIR`` in place of ``--backend`` (one of the two required)."""
    checked = parser.add_mutually_exclusive_group(required=True)
    checked.add_argument("--backend", type=reference_argument, metavar="NAME|MODULE:ATTRIBUTE",
                         help=f"the backend to {verb}: " + OPTION_HELP + "; a factory may return an object with only "
                         "some stages, or a dict {stage: callable}, and the others are not applicable")
    if results:
        checked.add_argument("--results", type=Path, metavar="DIR",
                             help="instead of a backend, the outputs another language computed from conformance "
                             "export's vectors: DIR/<case>.npz and DIR/implements.json (docs/comparing_runs.md); "
                             "give the export's selection")
    parser.add_argument("--rtol", type=option_value(float, relative_tolerance, "a number"), default=None,
                        help="pass threshold on the relative error, a finite number > 0 (default: "
                        + ", ".join(f"{r:g} in {t}" for t, r in DEFAULT_RTOL.items()) + ")")
    add_threads_option(parser)
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress bar (it goes to standard error; the results to standard output)")


def _add_search_parser(actions):
    parser = actions.add_parser("search", help="search for states where a backend and the reference disagree "
                                "(property-based, biased toward the extremes); shrink each to the smallest state that "
                                "shows it and save it as a case file for check --case")
    _add_check_options(parser, "search")
    parser.add_argument("--scene", type=Path, metavar="SCENE.toml",
                        help="draw the states in this scene (default: in the catalogue's scenes)")
    parser.add_argument("--stage", nargs="+", choices=SEARCH_STAGES,
                        help="stages to search (default: every one, or every one the scene's steps call)")
    budget = parser.add_mutually_exclusive_group()
    budget.add_argument("--budget", type=option_value(int, positive_count, "an integer"), default=DEFAULT_BUDGET,
                        metavar="N", help=f"states to try, all stages together (default {DEFAULT_BUDGET})")
    budget.add_argument("--time", type=option_value(float, positive_seconds, "a number"), metavar="T",
                        help="search for T seconds instead (the states are then not counted beforehand)")
    parser.add_argument("--seed", type=option_value(int, base_seed, "an integer"), default=0,
                        help="base seed of the search (default 0)")
    parser.add_argument("--out", type=Path, default=Path("conformance-search"), metavar="DIR",
                        help="where each shrunk disagreement is saved as <case>.npz (default: conformance-search)")
    parser.set_defaults(func=cmd_search)


def positive_count(value):
    """``value`` if it is an integer >= 1, else :class:`~mpmref.errors.ArgumentError`."""
    if value < 1:
        raise ArgumentError("budget", value, "an integer >= 1 (states to try)")
    return value


def positive_seconds(value):
    """``value`` if it is a finite number of seconds > 0, else :class:`~mpmref.errors.ArgumentError`."""
    if not (math.isfinite(value) and value > 0):
        raise ArgumentError("time", value, "a finite number of seconds > 0")
    return value


def add_parser(subparsers):
    """Add the ``conformance`` command with its ``export``, ``check`` and ``search`` subcommands to ``subparsers``."""
    parser = subparsers.add_parser("conformance", help="check a backend stage by stage against the NumPy "
                                   "reference, or export the test vectors for code in another language")
    actions = parser.add_subparsers(dest="conformance_command", required=True)
    export_parser = actions.add_parser("export", help="write one .npz per case and stage plus manifest.json")
    export_parser.add_argument("dir", type=Path, help="output folder (created if missing)")
    export_parser.add_argument("--implements", type=Path, metavar="FILE",
                               help="the catalogue's cases fitted to what your code declares in this file "
                               "(implements.json, as check --results reads it; docs/comparing_runs.md)")
    _add_selection(export_parser)
    export_parser.set_defaults(func=cmd_export)
    check_parser = actions.add_parser("check", help="run a backend on every case that it implements and print the "
                                      "error table (the others are listed as not applicable, with the reason)")
    _add_check_options(check_parser, "check", results=True)
    check_parser.add_argument("--verbose", action="store_true",
                              help="list every case, not only the failed ones, and each not-applicable case")
    _add_selection(check_parser)
    check_parser.set_defaults(func=cmd_check)
    _add_search_parser(actions)
    return parser
