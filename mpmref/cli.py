"""Command line: ``mpmref run SCENE.toml [--steps N | --until-step N | --t-end T] [--out DIR] [--resume |
--overwrite] [--backend B]``.

Exit status: 0 success; 2 a bad scene, command-line option, argument or backend reference (one line on stderr naming
the field, option, module or stage, the value and what is allowed); 3 any other mpmref error (an instability, a domain
exit, every particle gone); 130 interrupted (Ctrl-C; ``run`` saves a checkpoint and prints the resume command).
"""

import argparse
import contextlib
import copy
import functools
import importlib
import os
import shlex
import sys
import threading
import time
import warnings
from importlib.metadata import entry_points
from pathlib import Path
from typing import NamedTuple

from .backends import OPTION_HELP, reference_argument
from .errors import ArgumentError, BackendError, MpmrefError, SceneError
from .run import arguments

#: modules of this package that each add one subcommand through ``add_parser(subparsers)`` (it sets ``func``)
COMMAND_MODULES = ("mpmref.conformance", "mpmref.bench")
#: entry-point group through which other installed packages add subcommands (``verification`` adds ``verify``)
COMMAND_GROUP = "mpmref.commands"
#: exit status after Ctrl-C (128 + SIGINT), as shells report it
INTERRUPTED = 130
#: exit status when standard output is closed early (128 + SIGPIPE), as shells report it
BROKEN_PIPE = 141


class OptionError(Exception):
    """A command-line option is invalid (exit status 2); the message is the one line to print."""


class _Parser(argparse.ArgumentParser):
    """An argument parser that raises :class:`OptionError` instead of printing usage and exiting."""

    def error(self, message):
        raise OptionError(f"{message} (see '{self.prog} --help')")


def option_value(parse, check, kind, problem="is out of range"):
    """An argparse ``type``: ``text`` parsed by ``parse`` (``int``, ``float``, ``str``) and checked by ``check``, which
    raises :class:`~mpmref.errors.ArgumentError` (such as the definitions of :mod:`mpmref.run.arguments` that the Python
    API checks its arguments with); either failure becomes one line naming the option (exit status 2)."""
    def convert(text):
        try:
            value = parse(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {kind}") from None
        try:
            return check(value)
        except ArgumentError as exc:
            raise argparse.ArgumentTypeError(f"{text} {problem}; allowed: {exc.allowed}") from None

    return convert


#: ``--steps``: an integer >= 0
count_option = option_value(int, arguments.step_count, "an integer")
#: ``--threads``: an integer >= 1
threads_option = option_value(int, arguments.thread_count, "an integer")


def add_threads_option(parser):
    """Add ``--threads N`` (the Numba backend's thread count) to a command that runs a backend."""
    parser.add_argument("--threads", type=threads_option, metavar="N",
                        help="threads of the Numba backend (default: one per core; the summary says how many ran)")


def apply_threads(count):
    """Use ``count`` threads in the Numba backend here and in the worker processes started from now on
    (:func:`mpmref.backends.numba.threads.use_threads`); ``None`` leaves Numba's default."""
    if count is not None:
        from .backends.numba.threads import use_threads

        use_threads(count)
#: ``--t-end``: a finite number >= 0 (simulated time)
end_time_option = option_value(float, arguments.end_time, "a number")


def _parser(command=None):
    """The command line's parser: every subcommand's, or (``command``, the name of one) only that one's, so that a
    command does not import what the others need (``mpmref run`` does not load SciPy's statistics for ``compare``)."""
    parser = _Parser(prog="mpmref", description="Material Point Method reference toolkit")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a scene file and write a ParaView series")
    run.add_argument("scene", type=Path, help="scene TOML file")
    stop = run.add_mutually_exclusive_group()
    stop.add_argument("--steps", type=count_option, metavar="N",
                      help="take N more steps (from step 0, or from the checkpoint with --resume)")
    stop.add_argument("--until-step", type=count_option, metavar="N",
                      help="stop at step N, a total like the scene's time.steps (a resumed run ends there too)")
    stop.add_argument("--t-end", type=end_time_option, metavar="T", help="stop at simulated time T")
    run.add_argument("--out", type=Path, help="output folder (default: reports/<scene name>)")
    again = run.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue from the checkpoint in the output folder")
    again.add_argument("--overwrite", action="store_true",
                       help="replace the run already in the output folder (its frames, diagnostics and checkpoints)")
    run.add_argument("--backend", default="numpy", type=reference_argument, metavar="NAME|MODULE:ATTRIBUTE",
                     help=OPTION_HELP + " (default: numpy)")
    add_threads_option(run)
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.set_defaults(func=cmd_run)
    for module in COMMAND_MODULES:
        if command in (None, _command_name(module)):
            importlib.import_module(module).add_parser(sub)
    for plugin in _plugins():
        if command in (None, plugin.name):
            plugin.load()(sub)
    return parser


@functools.lru_cache(maxsize=1)
def _plugins():
    """The entry points of :data:`COMMAND_GROUP`, by name, read once per process (scanning the installed
    distributions' metadata costs a few milliseconds, and :func:`main` asks twice)."""
    return tuple(sorted(entry_points(group=COMMAND_GROUP), key=lambda e: e.name))


def _command_name(module):
    """The subcommand a module of :data:`COMMAND_MODULES` adds: its last name (``mpmref.bench`` adds ``bench``)."""
    return module.rsplit(".", 1)[1]


def _command_of(argv):
    """The subcommand ``argv`` names, if it is one of ours (``run``, :data:`COMMAND_MODULES`, the entry points of
    :data:`COMMAND_GROUP`); else ``None``: ``--help``, no command or a misspelt one need every subcommand's parser."""
    if not argv or argv[0].startswith("-"):
        return None
    known = {"run", *map(_command_name, COMMAND_MODULES), *(e.name for e in _plugins())}
    return argv[0] if argv[0] in known else None


def _format_summary(summary, out_dir, backend=None):
    final = summary["final"]
    against = "; against the start + entered - left" if "entered" in summary else ""
    lines = [
        f"steps            {summary['steps']} (each to a synchronised time; now at step {final['step']}, "
        f"t = {final['time']:.6g})",
        f"wall time        {summary['wall_s']:.3f} s (kernel compilation excluded)",
        f"particle-steps/s {summary['particle_steps_per_s']:.4g} (each particle's own steps)",
        f"particles        {final['n_particles']} (at the domain edge: {final['deleted']} deleted, "
        f"{final['clamped']} clamped back inside)",
        f"mass drift       {summary['mass_drift_rel']:.3e} (relative{against})",
        f"momentum drift   {summary['momentum_drift_rel']:.3e} (relative to total mass x rms speed; gravity and walls "
        f"change it{against})",
        f"energy drift     {summary['energy_drift_rel']:.3e} (relative, kinetic + affine + modes + elastic + "
        f"gravitational{against})",
        f"outputs          {out_dir} (open particles.pvd in ParaView"
        f"{', with rigid_bodies.pvd for the rigid bodies' if 'rigid0_x' in final else ''})",
    ]
    if "entered" in summary:
        lines.insert(4, f"in and out       {_exchanged(summary['entered'], 'entered')}; "
                        f"{_exchanged(summary['left'], 'left')} (over the run)")
    if backend is not None:
        version = f" {backend['version']}" if backend["version"] else " (no version given)"
        execution = f", {backend['execution']}" if backend["execution"] else ""
        lines.insert(0, f"backend          {backend['backend']} ({backend['class']}{version}){execution}")
    if "particle_updates" in summary:
        lines.insert(3, f"particle updates {summary['particle_updates']}: {summary['own_updates']} own steps + "
                        f"{summary['ghost_updates']} ghost updates; sync at the finest step "
                        f"({summary['finest_dt_ticks']} ticks) would make {summary['sync_particle_updates']:.0f}: "
                        f"update ratio {summary['update_ratio']:.2f}x ({summary['own_update_ratio']:.2f}x own steps "
                        f"only), a ratio of work, not of wall time")
        lines.insert(4, f"levels           {summary['levels']} at the end (log2 of each particle's step in ticks); "
                        f"{summary['stale_shadows']} stale shadows")
    return "\n".join(lines)


def _exchanged(record, direction):
    """``"entered: N particles, mass M, energy E"`` of a run summary's record of what entered or left."""
    return (f"{direction}: {record['particles']:.0f} particles, mass {record['mass']:.4g}, "
            f"energy {record['energy']:.4g}")


def _check_out(out_dir, resume, overwrite):
    """Refuse an ``--out`` that is a file, lies in a place that cannot be written, or holds a run already."""
    from .io.run_output import CHECKPOINT_NAME, run_files

    if out_dir.exists() and not out_dir.is_dir():
        raise OptionError(f"--out {out_dir}: this is an existing file; name a folder")
    parent = next(p for p in (out_dir, *out_dir.parents) if p.exists())
    if not parent.is_dir():
        raise OptionError(f"--out {out_dir}: {parent} is a file, so no folder can be made under it")
    if resume and not (out_dir / CHECKPOINT_NAME).is_file():
        raise OptionError(f"--resume: there is no checkpoint to resume from ({out_dir / CHECKPOINT_NAME} does not "
                          "exist); run without --resume to start")
    earlier = run_files(out_dir)
    if earlier and not (resume or overwrite):
        raise OptionError(f"--out {out_dir} already holds a run ({len(earlier)} files, e.g. {earlier[0].name}); "
                          "pass --resume to continue it or --overwrite to replace it")


def _open_simulation(scene, args, out_dir):
    """A new or resumed :class:`~mpmref.run.simulation.Simulation` writing to ``out_dir``."""
    from .io.run_output import clear_run
    from .run.simulation import Simulation

    try:
        if args.resume:
            return Simulation.resume(scene, out_dir, backend=args.backend)
        if args.overwrite:
            clear_run(out_dir)
        return Simulation(scene, backend=args.backend, out_dir=out_dir)
    except OSError as exc:
        raise OptionError(f"--out {out_dir}: cannot write there ({exc.strerror or exc})") from None


def _warm_up(sim, backend, who="mpmref"):
    """Compile the backend's kernels (and an asynchronous stepper's bookkeeping) for this scene before the timed
    run, saying so, where they are cached, and how long it took (:func:`compiling`). A kernel whose parallel build
    is not cached yet is compiled serially, and the parallel builds in another process while the run goes on
    (:mod:`mpmref.run.first_run`): the started :class:`~mpmref.run.first_run.ParallelBuild`, or ``None``."""
    from .run import first_run

    if not sim.compiles:
        return None
    with compiling(who):
        build = first_run.warm_up(sim, backend)
    if build is not None:
        print(f"{who}: the run starts on serial kernels; their parallel builds compile in the background, and the run "
              "goes on with them once they are cached", file=sys.stderr)
    return build


@contextlib.contextmanager
def compiling(who="mpmref", stream=None, every_s=1.0):
    """Say on ``stream`` (standard error) that the kernels of a scene are being compiled, the first run only, and
    where Numba caches them; on a terminal, the seconds so far, every ``every_s``; then how long it took."""
    stream = stream or sys.stderr
    cache = os.environ.get("NUMBA_CACHE_DIR") or "Numba's default cache, beside the sources"
    line = f"{who}: compiling kernels for this scene (the first run only: they are cached in {cache})…"
    print(line, end="", file=stream, flush=True)
    start, done = time.perf_counter(), threading.Event()
    ticker = None
    if stream.isatty():
        def tick():
            while not done.wait(every_s):
                print(f"\r{line} {time.perf_counter() - start:.0f} s", end="", file=stream, flush=True)
        ticker = threading.Thread(target=tick, daemon=True)
        ticker.start()
    try:
        yield
    finally:
        done.set()
        if ticker is not None:
            ticker.join()
            print(f"\r{line}", end="", file=stream)
        print(f" done in {time.perf_counter() - start:.1f} s", file=stream, flush=True)


def _switch_when_built(build, who="mpmref"):
    """A run's per-step hook that goes on with the parallel kernels once ``build`` has cached them, saying so at that
    step (``None`` without a build)."""
    if build is None:
        return None

    def switch(sim):
        if build.poll():
            print(f"{who}: parallel kernels ready; the run goes on with them from step {sim.step_count + 1}",
                  file=sys.stderr)

    return switch


def resume_command(args, out_dir):
    """The ``mpmref run`` command line that continues the interrupted run (same stop, same backend)."""
    words = ["mpmref", "run", str(args.scene), "--out", str(out_dir), "--resume"]
    if args.steps is not None or args.until_step is not None:  # the same end step as the interrupted run
        words += ["--until-step", str(args.until_step if args.steps is None else args.start_step + args.steps)]
    if args.t_end is not None:
        words += ["--t-end", repr(args.t_end)]
    if args.backend != "numpy":
        words += ["--backend", args.backend]
    if args.threads is not None:
        words += ["--threads", str(args.threads)]
    return shlex.join(words + (["--no-progress"] if args.no_progress else []))


#: a run or a study estimated to take longer than this (seconds) is warned about before it starts
LONG_RUN_S = 3600.0


class Length(NamedTuple):
    """The estimated length of a run (:func:`run_length`): ``steps`` to its end time, of ``particles`` at the start,
    at the ``rate`` (particle-steps per second) that ``probed`` steps took here: ``seconds`` in all."""

    steps: float
    particles: int
    rate: float
    probed: int
    seconds: float

    def __str__(self):
        return (f"{self.steps:.3g} steps of {self.particles} particles at {self.rate:.3g} particle-steps/s, measured "
                f"on {self.probed} steps here")


def run_length(scene, backend, t_end, state=None, budget_s=0.1, most_steps=20):
    """The estimated :class:`Length` of a run of ``scene`` on ``backend`` from ``state`` (default: its start) to time
    ``t_end``: a copy steps here, without outputs or warnings, for about ``budget_s`` seconds (one step at least,
    ``most_steps`` at most); the steps to ``t_end`` at their mean Δt, times the particles, against the particle-steps
    per second they took. A CFL Δt that shrinks later makes the run longer. ``None`` when a step fails: the run
    itself reports why."""
    from .run.simulation import Simulation

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            probe = Simulation(scene, backend=backend)
            if state is not None:
                probe.state = copy.deepcopy(state)
            probe.warm_up()  # already compiled for the run: loaded from memory or Numba's cache
            t0, spent, steps, updates = probe.time, 0.0, 0, 0
            while steps < 1 or (spent < budget_s and steps < most_steps and probe.time < t_end):
                tick = time.perf_counter()
                probe.step(t_end=t_end)
                spent, steps, updates = spent + time.perf_counter() - tick, steps + 1, updates + probe.last_updates
    except Exception:  # the run that follows raises it with its context (a checkpoint, exit 3)
        return None
    total = steps * (t_end - t0) / (probe.time - t0)
    return Length(total, probe.n_particles, updates / max(spent, 1e-9), steps, total * spent / steps)


def length_line(command, seconds, how, stop):
    """The line that announces a run's or a study's estimated length (``seconds``; ``how``: how it was estimated):
    a warning past :data:`LONG_RUN_S`, with ``stop``, what Ctrl-C does."""
    if seconds > LONG_RUN_S:
        return f"{command}: warning: this will take about {duration(seconds)} ({how}); {stop}"
    return f"{command}: the steps will take about {duration(seconds)} ({how})"


def duration(seconds):
    """``seconds`` in the unit that reads best: ``"0.14 s"``, ``"40 s"``, ``"12 min"``, ``"3.5 h"``, ``"9.1 days"``,
    ``"1220 years"``, ``"3.2e+04 years"``."""
    units = (("s", 1, 120), ("min", 60, 120), ("h", 3600, 48), ("days", 86400, 730), ("years", 365.25 * 86400, None))
    unit, size = next((unit, size) for unit, size, below in units if below is None or seconds < below * size)
    value = seconds / size
    return f"{value:.0f} {unit}" if 10 <= value < 1e4 else f"{value:.2g} {unit}"


def _announce_length(sim, args):
    """Print the estimated length of running ``sim`` to ``--t-end`` (:func:`run_length`) on standard error."""
    length = run_length(sim.scene, args.backend, args.t_end, sim.state)
    if length is not None:
        print(length_line("mpmref", length.seconds, length, "Ctrl-C stops it with a checkpoint that --resume "
                          "continues"), file=sys.stderr)


def cmd_run(args):
    from .scene import Scene

    scene = Scene.from_toml(args.scene)
    out_dir = args.out or Path("reports") / scene.name
    _check_out(out_dir, args.resume, args.overwrite)
    apply_threads(args.threads)
    sim = _open_simulation(scene, args, out_dir)
    build = _warm_up(sim, args.backend)
    if args.t_end is not None:
        _announce_length(sim, args)
    args.start_step = sim.step_count
    try:
        summary = sim.run(steps=args.steps, until_step=args.until_step, t_end=args.t_end,
                          progress=not args.no_progress, each_step=_switch_when_built(build))
    except KeyboardInterrupt:
        path = sim.save_checkpoint("interrupted")
        print(f"mpmref: interrupted at step {sim.step_count}; checkpoint saved to {path}; resume with: "
              f"{resume_command(args, out_dir)}", file=sys.stderr)
        return INTERRUPTED
    finally:
        if build is not None:
            build.stop()
    print(_format_summary(summary, out_dir, sim.backend_info))
    return 0


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Print a warning as one line (no source line) on stderr."""
    print(f"mpmref: warning: {message}", file=sys.stderr)


@contextlib.contextmanager
def _one_line_warnings():
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        yield


def main(argv=None):
    try:
        words = list(sys.argv[1:] if argv is None else argv)
        args = _parser(_command_of(words)).parse_args(words)
        args.argv = words  # the command's words, for a line that resumes it
        with _one_line_warnings():
            return args.func(args)
    except OptionError as exc:
        print(f"mpmref: {exc}", file=sys.stderr)
        return 2
    except SceneError as exc:
        print(f"mpmref: invalid scene: {exc}", file=sys.stderr)
        return 2
    except BackendError as exc:
        print(f"mpmref: invalid backend: {exc}", file=sys.stderr)
        return 2
    except ArgumentError as exc:
        print(f"mpmref: invalid argument: {exc}", file=sys.stderr)
        return 2
    except MpmrefError as exc:
        print(f"mpmref: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("mpmref: interrupted", file=sys.stderr)
        return INTERRUPTED
    except BrokenPipeError:  # the reader of standard output went away (`mpmref ... | head`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return BROKEN_PIPE


if __name__ == "__main__":
    sys.exit(main())
