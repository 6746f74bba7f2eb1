"""``mpmref bench``: Table 2 (P2G/G2P of MPM and MLS-MPM), whole-step throughput and a Taichi peer.

Every figure is the median of ``repeats`` timed calls; the first call with each setting (which
includes Numba's or Taichi's JIT compilation) is reported apart as ``first_call_s``. Results go to a
JSON document (schema :data:`SCHEMA`, written atomically with ``--json``) and to readable tables.
See ``docs/performance.md``.

Sections of the JSON document (each ``null`` when not run):

* ``table2``: ``setup``; ``timings`` (backend, threads, dtype, method ``mpm``/``mls``, stage
  ``prepare``/``p2g``/``g2p``, ``first_call_s``, ``times_s``, ``median_s``); ``ratios`` (MPM over
  MLS-MPM for ``p2g`` and ``g2p``); ``memory`` (:mod:`mpmref.bench.memory`).
* ``table2_2d``: the same in 2D (4 particles per cell, as many particles as ``table2``), without ``memory``.
* ``throughput``: ``cases`` (case, dim, cells, particles, dt, steps) and ``results`` (case, backend,
  threads, dtype, timing, ``particle_steps_per_s``, ``vs_numpy``).
* ``async``: ``results`` (case, backend, threads, particles, levels, ``async`` and ``sync`` timings with
  their particle updates, ``updates_ratio``, ``own_updates_ratio``, ``wall_ratio``, ``energy_difference``,
  ``position_difference_dx``; ``sync_cfl`` (synchronous at its own CFL step) and ``one_level`` (the control)
  timings, ``cfl_wall_ratio``, ``one_level_overhead``, ``ghost_efficiency``, ``implementation_efficiency``, and in
  ``async`` the split ``stages_s``/``stepping_s`` and the bookkeeping's ``counts``; :mod:`mpmref.bench.asynchronous`).
* ``stages``: ``stages`` and ``results`` (case, backend, threads, dtype, particles, ``step_s``, ``stages_s``
  per stage, ``stress_inside_p2g``, ``stress_alone_s``, ``p2g_fused`` whether the step's P2G was the fused one;
  :mod:`mpmref.bench.stage_times`).
* ``scaling``: ``sizes`` (dim, cells, particles, a timing record, ``ns_per_particle_step``) and ``threads``
  (the 262 144-particle 2D case at each thread count, ``speedup_over_1``).
* ``domain``: ``domains``, ``body_cells`` and ``results`` (backend, dtype, threads, cells, nodes, particles, a
  timing record, ``step_s``, ``step_over_smallest``, ``baseline_bytes``, ``peak_bytes``;
  :mod:`mpmref.bench.domain`).
* ``cpic``: ``case`` (cells, particles, bodies, segments, dt, steps), ``goal`` and ``results`` (backend,
  threads, dtype, particles, ``coupled`` and ``plain`` timings of whole steps with and without the rigid
  bodies, ``ratio``, ``coupled_stages_s``; :mod:`mpmref.bench.cpic`).
* ``busy``: ``scene``, ``particles``, ``steps``, ``threading_layer`` and ``results`` (per ``load``, ``"as it is"`` and
  ``"one core busy"``: ``times_s`` and ``median_s`` on 1 and 2 threads, ``ratio`` two over one;
  :mod:`mpmref.bench.busy`).
* ``ledger``: ``cases`` (case, scene, particles, dt, steps) and ``results`` (case, backend, threads, particles, the
  ``off`` and ``on`` timing records of the same steps without and with the energy ledger, ``ratio`` on / off;
  :mod:`mpmref.bench.ledger`).
* ``startup`` (``--only startup``): a first ``mpmref run`` of two examples and a cold ``verify --quick`` from empty
  caches, here and at ``--against REV`` (a git worktree) in the same run: ``against``, ``this``, ``repeats``, the
  load averages and ``rows`` (command, ``this`` and ``against`` runs with ``wall_s``, ``cpu_s``, ``status``, and
  the median wall-time ``ratio``; :mod:`mpmref.bench.startup`).
* ``compile`` (``--only compile``): the compile census of a first run of each example from an empty cache: ``root``,
  ``steps``, the load averages and ``scenes`` (scene, ``status``, ``configurations``, ``signatures``,
  ``compile_cpu_s``, ``process_cpu_s`` and ``kernels``: kernel, signatures, ``cpu_s``;
  :mod:`mpmref.bench.compile_census`).
* ``cuda`` (``--only cuda``): the GPU backend beside the GPU yardstick and Numba on every core, ``available``,
  ``device``, ``results`` and its own ``goals`` (:mod:`mpmref.bench.gpu`).
* ``yardstick``: the records given with ``--yardstick`` (a hand-written program's runs), as given.
* ``goals``: one record per performance goal (:mod:`mpmref.bench.goals`): ``name``, ``figure`` (``null``
  when this run did not measure it), ``bound``, ``at_most``, ``where``, ``met``.
* ``peer``: ``available`` (and ``message`` if not), ``version``, ``dtype``, ``steps`` and ``results``
  (case, particles, threads, backend, ``mpmref`` and ``taichi`` timings, ``ratio``,
  ``mean_position_difference``, ``bound``, ``free_flight``, ``agree``; :mod:`mpmref.bench.peer`).
"""

import argparse
import datetime
import json
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

from ..backends import BACKENDS, reference_argument
from ..backends.numba import twin
from ..io.atomic import write_text_atomic
from .goals import goals_section, render_goals
from .scenes import table2_cells

# the names of the sections (:data:`mpmref.bench.sections.SECTIONS`), and of those a run without --only runs
from .sections import BY_NAME
from .sections import DEFAULT_NAMES as DEFAULT_SECTIONS
from .sections import NAMES as SECTIONS
from .startup import DEFAULT_AGAINST
from .timing import check_threads

SCHEMA = "mpmref-bench/1"
DESCRIPTION = ("Time P2G and G2P of classic MPM and MLS-MPM (the talk's Table 2), whole-step throughput, and "
               "optionally a Taichi peer on the same scenes. Every figure is the median of --repeats; JIT "
               "compilation is reported apart. See docs/performance.md.")
DEFAULT_PARTICLES = 1_000_000
QUICK_PARTICLES = 4096
FULL_CELLS = 100
DTYPE_NAMES = {"f32": "float32", "f64": "float64", "float32": "float32", "float64": "float64"}


@dataclass(frozen=True)
class BenchOptions:
    """What ``mpmref bench`` runs.

    Attributes
    ----------
    size : int            Table-2 particle count, rounded to ``8 n**3`` (``n`` cells per side)
    full : bool           Table 2 at the paper's 100**3 cells (8 M particles), overriding ``size``, the
                          scaling table up to 1 M particles, and the async storks up to 205 000 particles
    plot : str or None    write the scaling plot (PNG) here, and the async series plot (as ``NAME_async.png``
                          beside it, or here when the async section runs alone)
    threads : tuple       thread counts (Numba and the peer; NumPy always runs on one)
    dtypes : tuple        ``"float32"`` and/or ``"float64"``
    backends : tuple      mpmref backends to time
    sections : tuple      which of :data:`SECTIONS` to run
    repeats : int         timed repeats per figure (the median is reported)
    steps : int           steps per timed repeat in the throughput section
    peer_steps : int      steps per timed repeat in the peer section
    quick : bool          tiny throughput and peer cases (a smoke test: the figures mean nothing)
    memory : bool         run the peak-memory probes (Table 2, domain)
    yardstick : tuple     records of a hand-written program's runs (``--yardstick``), which goals compare with
    against : str         the older commit the startup section measures beside this checkout
    """

    size: int = DEFAULT_PARTICLES
    full: bool = False
    threads: tuple = (1, 2)
    dtypes: tuple = ("float32", "float64")
    backends: tuple = BACKENDS
    sections: tuple = DEFAULT_SECTIONS
    repeats: int = 3
    steps: int = 10
    peer_steps: int = 100
    quick: bool = False
    memory: bool = True
    plot: str = None
    yardstick: tuple = ()
    against: str = DEFAULT_AGAINST

    @property
    def table2_cells(self):
        return FULL_CELLS if self.full else table2_cells(self.size)

    @property
    def table2_2d_cells(self):
        """Cells per side of the 2D block with as many particles as the 3D one."""
        return table2_cells(8 * self.table2_cells**3, dim=2)


def _to_stderr(message):
    print(message, file=sys.stderr, flush=True)


def run_bench(options, log=print, progress=_to_stderr):
    """Run the selected sections and return the JSON dict.

    Each section's table goes to ``log`` as soon as it is complete. ``progress`` (standard error by
    default) gets a line when each section starts and when it finishes (with its wall time), and one per
    measurement being started.
    """
    check_threads(options.backends, options.threads)
    with twin.builds("parallel"):  # what the threads of the Numba backend run, whatever the environment chose
        return _run_sections(options, log, progress)


def _run_sections(options, log, progress):
    """:func:`run_bench`'s work."""
    results = {"schema": SCHEMA, "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
               "environment": environment(), "options": asdict(options), **{name: None for name in SECTIONS}}
    for i, name in enumerate(options.sections, 1):
        tag = f"[{i}/{len(options.sections)}] {name}"
        progress(f"{tag}: started")
        start = time.perf_counter()
        results[name] = BY_NAME[name].run(options, progress)
        progress(f"{tag}: finished in {time.perf_counter() - start:.1f} s")
        log(BY_NAME[name].render(results[name]) + "\n")
    results["yardstick"] = list(options.yardstick)
    results["goals"] = goals_section(results)
    log(render_goals(results["goals"]) + "\n")
    return results


def environment():
    """Versions and machine facts that the figures depend on."""
    versions = {}
    for package in ("numpy", "numba", "taichi"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {"python": platform.python_version(), "platform": platform.platform(), "cpu": cpu_model(),
            "cpu_count": os.cpu_count(), "usable_cpus": usable, **versions}


def cpu_model():
    """The CPU's model name from ``/proc/cpuinfo`` (Linux), else what :func:`platform.processor` says."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def write_json(results, path):
    """Write the results as JSON atomically (temporary file, then rename)."""
    write_text_atomic(path, json.dumps(results, indent=2) + "\n")


# ------------------------------------------------------------------------------------ command line
def _positive(text):
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} is not a positive integer")
    return value


def _thread_list(text):
    return tuple(_positive(part) for part in text.split(","))


def _dtype_list(text):
    names = [part.strip() for part in text.split(",")]
    unknown = [n for n in names if n not in DTYPE_NAMES]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown dtype(s) {unknown}; use f32, f64 or f32,f64")
    return tuple(DTYPE_NAMES[n] for n in names)


def _backend_list(text):
    """``--backends``: comma-separated backend references (:func:`mpmref.backends.reference_argument`; one that
    does not resolve stops the command with exit status 2 before any work)."""
    return tuple(reference_argument(part.strip()) for part in text.split(","))


def _yardstick(text):
    """``--yardstick FILE``: the records of a JSON-lines file (each with ``dim``, ``n_particles``, ``threads``,
    ``dtype`` and ``particle_steps_per_s``)."""
    try:
        lines = Path(text).read_text(encoding="utf-8").splitlines()
        records = [json.loads(line) for line in lines if line.strip()]
    except (OSError, ValueError) as exc:
        raise argparse.ArgumentTypeError(f"{text}: cannot read JSON lines ({exc})") from None
    keys = {"dim", "n_particles", "threads", "dtype", "particle_steps_per_s"}
    bad = [r for r in records if not isinstance(r, dict) or not keys <= set(r)]
    if bad:
        raise argparse.ArgumentTypeError(f"{text}: every line needs the keys {sorted(keys)}")
    return tuple(records)


def add_parser(subparsers):
    """Add the ``bench`` subcommand to an argparse ``subparsers`` object (sets ``func``)."""
    p = subparsers.add_parser("bench", help="time Table 2 (P2G/G2P), whole-step throughput and a Taichi peer",
                              description=DESCRIPTION)
    p.add_argument("--size", type=_positive, help=f"Table-2 particles (default {DEFAULT_PARTICLES:,}; "
                   f"{QUICK_PARTICLES} with --quick), rounded to 8 n^3")
    p.add_argument("--full", action="store_true",
                   help="Table 2 at the paper's 100^3 cells (8 M particles); scaling up to 1 M particles; the async "
                   "storks up to 205 000 particles (2D) and 127 000 (3D)")
    p.add_argument("--plot", help="write the scaling plot (PNG) to this file, and the async series plot beside it "
                   "(NAME_async.png; to this file when --only async)")
    p.add_argument("--threads", type=_thread_list, default=(1, 2), help="thread counts, e.g. 1,2 (default)")
    p.add_argument("--dtype", type=_dtype_list, default=("float32", "float64"), help="f32, f64 or f32,f64 (default)")
    p.add_argument("--backends", type=_backend_list, default=BACKENDS,
                   help=f"backends to time, comma separated: numpy, numba, a plugin's name or MODULE:ATTRIBUTE "
                   f"(default: {','.join(BACKENDS)})")
    p.add_argument("--vs", choices=("taichi",), help="also compare with a peer code on the same scenes")
    p.add_argument("--only", choices=SECTIONS, help="run one section (peer implies --vs taichi)")
    p.add_argument("--repeats", type=_positive, default=3, help="timed repeats per figure; the median is reported")
    p.add_argument("--steps", type=_positive, default=10, help="steps per timed repeat, throughput (default 10)")
    p.add_argument("--peer-steps", type=_positive, default=100, help="steps per timed repeat, peer (default 100)")
    p.add_argument("--against", metavar="REV", default=DEFAULT_AGAINST,
                   help=f"the startup section's older commit, run beside this checkout (default {DEFAULT_AGAINST})")
    p.add_argument("--quick", action="store_true", help="tiny sizes: a smoke test whose figures mean nothing")
    p.add_argument("--no-memory", action="store_true", help="skip the peak-memory probes (Table 2, domain)")
    p.add_argument("--json", dest="json_path", help="write the results to this JSON file (atomically)")
    p.add_argument("--yardstick", type=_yardstick, metavar="FILE",
                   help="JSON lines of a hand-written program's runs (dim, n_particles, threads, dtype, "
                   "particle_steps_per_s), run beside this command: the goals compare the throughput cases with them")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress lines (they go to standard error; the tables to standard output)")
    p.set_defaults(func=cmd_bench)
    return p


def options_from_args(args):
    """:class:`BenchOptions` from parsed command-line arguments."""
    if args.only:
        sections = (args.only,)
    else:
        sections = DEFAULT_SECTIONS + (("peer",) if args.vs else ())
    size = args.size or (QUICK_PARTICLES if args.quick else DEFAULT_PARTICLES)
    return BenchOptions(size=size, full=args.full, threads=args.threads, dtypes=args.dtype, backends=args.backends,
                        sections=sections, repeats=args.repeats, steps=args.steps, peer_steps=args.peer_steps,
                        quick=args.quick, memory=not args.no_memory, plot=args.plot, yardstick=args.yardstick or (),
                        against=args.against)


def _silent(message):
    """A ``progress`` callable that drops the line (``--no-progress``)."""


def cmd_bench(args):
    """Run ``mpmref bench``: tables on standard output, progress on standard error; exit status 0."""
    results = run_bench(options_from_args(args), progress=_silent if args.no_progress else _to_stderr)
    if args.json_path:
        write_json(results, args.json_path)
        print(f"results written to {args.json_path}")
    return 0
