"""Command line: ``mpmref run SCENE.toml [--steps N | --t-end T] [--out DIR] [--resume]``."""

import argparse
import importlib
import sys
from importlib.metadata import entry_points
from pathlib import Path

from .backends import BACKENDS
from .errors import MpmrefError, SceneError

#: modules of this package that each add one subcommand through ``add_parser(subparsers)`` (it sets ``func``)
COMMAND_MODULES = ("mpmref.conformance", "mpmref.bench")
#: entry-point group through which other installed packages add subcommands (``verification`` adds ``verify``)
COMMAND_GROUP = "mpmref.commands"


def _parser():
    parser = argparse.ArgumentParser(prog="mpmref", description="Material Point Method reference toolkit")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a scene file and write a ParaView series")
    run.add_argument("scene", type=Path, help="scene TOML file")
    stop = run.add_mutually_exclusive_group()
    stop.add_argument("--steps", type=int, help="total number of steps (overrides time.steps / time.t_end)")
    stop.add_argument("--t-end", type=float, help="end time (overrides time.steps / time.t_end)")
    run.add_argument("--out", type=Path, help="output folder (default: reports/<scene name>)")
    run.add_argument("--resume", action="store_true", help="continue from the checkpoint in the output folder")
    run.add_argument("--backend", default="numpy", choices=BACKENDS, help="execution backend (default: numpy)")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.set_defaults(func=cmd_run)
    for module in COMMAND_MODULES:
        importlib.import_module(module).add_parser(sub)
    for plugin in sorted(entry_points(group=COMMAND_GROUP), key=lambda e: e.name):
        plugin.load()(sub)
    return parser


def _format_summary(summary, out_dir):
    final = summary["final"]
    lines = [
        f"steps            {summary['steps']} (now at step {final['step']}, t = {final['time']:.6g})",
        f"wall time        {summary['wall_s']:.3f} s",
        f"particle-steps/s {summary['particle_steps_per_s']:.4g}",
        f"particles        {final['n_particles']} (deleted at the domain edge: {final['deleted']})",
        f"mass drift       {summary['mass_drift_rel']:.3e} (relative)",
        f"momentum drift   {summary['momentum_drift_rel']:.3e} (relative to total mass x rms speed; gravity and walls change it)",
        f"energy drift     {summary['energy_drift_rel']:.3e} (relative, kinetic + affine + modes + elastic + gravitational)",
        f"outputs          {out_dir} (open particles.pvd in ParaView)",
    ]
    if "particle_updates" in summary:
        lines.insert(3, f"particle updates {summary['particle_updates']} ({summary['ghost_updates']} of them ghosts); "
                        f"updates saved against sync: {summary['updates_saved']:.2f}x (sync at the finest step, "
                        f"{summary['finest_dt_ticks']} ticks)")
    return "\n".join(lines)


def cmd_run(args):
    from .scene import Scene
    from .simulation import Simulation

    scene = Scene.from_toml(args.scene)
    out_dir = args.out or Path("reports") / scene.name
    if args.resume:
        sim = Simulation.resume(scene, out_dir, backend=args.backend)
    else:
        sim = Simulation(scene, backend=args.backend, out_dir=out_dir)
    steps = None if args.steps is None else max(0, args.steps - sim.step_count)
    summary = sim.run(steps=steps, t_end=args.t_end, progress=not args.no_progress)
    print(_format_summary(summary, out_dir))
    return 0


def main(argv=None):
    args = _parser().parse_args(argv)
    try:
        return args.func(args)
    except SceneError as exc:
        print(f"mpmref: invalid scene: {exc}", file=sys.stderr)
        return 2
    except MpmrefError as exc:
        print(f"mpmref: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
