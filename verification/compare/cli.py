"""``mpmref compare SCENE.toml FRAMES [--backend B] [--members N] [--seed S] [--dtype T] [--out DIR]``
``[--scheduler ADDRESS] [--workers N] [--no-progress]``

Judges the frames another code wrote from the start of SCENE.toml (``mpmref export``) against an ensemble of mpmref's
own runs of the scene perturbed at round-off, frame by frame; writes ``results.json``, ``index.html``, the figures and
the VTK file of where the code's particles part from the control's into DIR (default ``reports/compare/<scene>``).
Standard output gets the verdict: the first frame where the code leaves the ensemble, its statistics and materials.

Exit status: 0 every frame lies in the ensemble; 1 the code leaves it; 2 a bad scene, option or frame (one line
naming the file and the reason, before any run); 130 interrupted.
"""

import sys
from pathlib import Path

from mpmref.backends import OPTION_HELP, reference_argument
from mpmref.cli import option_value
from mpmref.errors import ArgumentError
from mpmref.exchange.cli import scene_in
from mpmref.exchange.frames import FrameError
from mpmref.scene import DTYPES

from ..framework.executor import Executor
from .comparison import DEFAULT_MEMBERS, MIN_MEMBERS, compare
from .report import summary, write_report


def _at_least(minimum, what):
    def check(value):
        if value < minimum:
            raise ArgumentError(what, value, f"an integer >= {minimum}")
        return value

    return option_value(int, check, "an integer")


def cmd_compare(args):
    """Run the comparison, write its report, print the verdict; exit status 0 (passed) or 1."""
    scene = scene_in(args.scene)
    executor = Executor(args.scheduler, args.workers)
    try:
        comparison = compare(scene, args.frames, backend=args.backend, members=args.members, seed=args.seed,
                             dtype=args.dtype, executor=executor, progress=not args.no_progress)
    except FrameError as exc:
        print(f"mpmref: invalid frame: {exc}", file=sys.stderr)
        return 2
    out = args.out or Path("reports") / "compare" / comparison.scene.name
    index = write_report(comparison, out)
    print(summary(comparison))
    print(f"report: {index} ({len(comparison.frames)} frames, {comparison.members} members, "
          f"{comparison.wall_s:.1f} s)")
    return 0 if comparison.passed else 1


def add_parser(subparsers):
    """Add the ``compare`` command to ``subparsers`` (the entry point ``mpmref.commands: compare``)."""
    p = subparsers.add_parser("compare", help="judge the frames another code wrote against an ensemble of the "
                              "reference perturbed at round-off", description=__doc__.split("\n\n")[1])
    p.add_argument("scene", type=Path, help="scene TOML file (the one exported with mpmref export)")
    p.add_argument("frames", type=Path, help="the code's frames: a .pvd series, a folder of .vtu/.vtp/.vtk/.npz/.csv "
                   "files, or one file")
    p.add_argument("--backend", default="numba", type=reference_argument, metavar="NAME|MODULE:ATTRIBUTE",
                   help=OPTION_HELP + " (default: numba): the backend that runs the ensemble")
    p.add_argument("--members", type=_at_least(MIN_MEMBERS, "--members"), default=DEFAULT_MEMBERS, metavar="N",
                   help=f"perturbed members besides the control (default {DEFAULT_MEMBERS}, at least {MIN_MEMBERS})")
    p.add_argument("--seed", type=_at_least(0, "--seed"), default=0, help="seed of the perturbations (default 0)")
    p.add_argument("--dtype", choices=DTYPES, help="the code's precision (default: float32 when its frames store "
                   "float32 positions, else the scene's)")
    p.add_argument("--out", type=Path, metavar="DIR", help="report folder (default: reports/compare/<scene name>)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run the members on this dask.distributed scheduler")
    p.add_argument("--workers", type=_at_least(1, "--workers"), metavar="N",
                   help="local worker processes (default: CPU cores; 1 runs in this process)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (standard error)")
    p.set_defaults(func=cmd_compare)
    return p
