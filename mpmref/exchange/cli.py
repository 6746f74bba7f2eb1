"""``mpmref export SCENE.toml DIR [--dtype T]``: the start of a scene for a code in any language
(:mod:`mpmref.exchange.start`).

Exit status: 0 written; 2 a bad scene or option (one line on standard error).
"""

from pathlib import Path

from ..scene import DTYPES, Scene
from ..scene.builder import read_scene_file
from .start import PARTICLE_FILES, SCENE_FILE, export_start


def scene_in(path, dtype=None):
    """The scene of the file ``path``, in ``dtype`` if given (else its own)."""
    data = read_scene_file(path)
    if dtype is not None:
        data["dtype"] = dtype
    return Scene.from_dict(data, base_dir=Path(path).parent)


def cmd_export(args):
    """Write the start of ``args.scene`` into ``args.dir``; say what was written."""
    scene = scene_in(args.scene, args.dtype)
    export_start(scene, args.dir)
    files = ", ".join(PARTICLE_FILES.values())
    print(f"wrote the start of scene '{scene.name}' ({scene.dim}D, {scene.dtype.name}) to {args.dir}: {files} and "
          f"{SCENE_FILE} (every number of the scene); run your code from it, then: mpmref compare {args.scene} "
          "<your frames>")
    return 0


def add_parser(subparsers):
    """Add the ``export`` command to ``subparsers`` (the entry point ``mpmref.commands: export``)."""
    parser = subparsers.add_parser("export", help="write a scene's start (particles as .npz, CSV and VTK, every number "
                                   "of the scene as scene.json) for a code in any language")
    parser.add_argument("scene", type=Path, help="scene TOML file")
    parser.add_argument("dir", type=Path, help="output folder (created if missing)")
    parser.add_argument("--dtype", choices=DTYPES, help="floating-point type of the particles (default: the scene's)")
    parser.set_defaults(func=cmd_export)
    return parser
