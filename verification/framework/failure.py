"""Where an exception inside a case happened: the scene that was running and the backend's stage that raised.

A case's simulations run in worker processes (:mod:`~verification.framework.executor`), whose tracebacks reach the
main process only as text. So the place is read from the traceback where the exception is raised (:func:`locate`,
called in the worker before the exception is sent back, and again by :func:`~verification.framework.registry.run_case`
for one raised in the main process) and kept on the exception itself: ``exc.verification_where``, a
:class:`Where`, travels with it (an exception's attributes are pickled with it) and a note says it in its traceback.

The stage is the innermost call from mpmref's own code (the steppers, the conformance stages, the observers) or from a
case into a method of the backend named as a stage of the contract (:mod:`mpmref.backends.base`): ``p2g``,
``grid_update``, ``g2p``, .... An exception raised outside every stage (in the case's own code, or in mpmref on what a
stage returned) is placed at the innermost frame that is not in the standard library or an installed library. The
scene is the innermost one in reach of a frame: a local ``scene``, or the ``scene`` of a local ``self``, ``sim``,
``simulation`` or ``backend``.
"""

import sysconfig
import traceback
from dataclasses import dataclass
from pathlib import Path

from mpmref import Scene
from mpmref.backends.base import ASYNC_BACKEND_STAGES, BACKEND_STAGES, CPIC_BACKEND_STAGES, FUSED_BACKEND_STAGES

#: the names of a backend's stages (the contract of :mod:`mpmref.backends.base`)
STAGES = BACKEND_STAGES + ASYNC_BACKEND_STAGES + CPIC_BACKEND_STAGES + FUSED_BACKEND_STAGES
#: the folders whose code calls a backend's stages: mpmref (but its backends) and the verification cases
_MPMREF = Path(__file__).resolve().parents[2] / "mpmref"
_CALLERS = (_MPMREF, Path(__file__).resolve().parents[1])
_BACKENDS = _MPMREF / "backends"
#: the installed libraries and the standard library: an exception raised there is placed at the code that called them
_LIBRARIES = tuple(Path(sysconfig.get_paths()[key]).resolve() for key in ("stdlib", "purelib", "platlib"))
#: the locals that hold a scene, or an object whose ``scene`` is one
_HOLDERS = ("self", "sim", "simulation", "backend")


@dataclass(frozen=True)
class Where:
    """The scene (its name) and the stage (``"stage g2p of Mpm88Backend"``, or the function outside the stages)
    where an exception was raised; ``None`` for what could not be found."""

    scene: str | None
    stage: str | None

    def text(self):
        scene = f"scene '{self.scene}'" if self.scene else "scene unknown"
        return f"{scene}, {self.stage or 'stage unknown'}"


def locate(exc):
    """Find where ``exc`` was raised and keep it on the exception (``exc.verification_where``, and a note); the
    innermost place found first is kept. Returns the :class:`Where`."""
    found = getattr(exc, "verification_where", None)
    if found is not None:
        return found
    frames = [frame for frame, _ in traceback.walk_tb(exc.__traceback__)]
    where = Where(_scene(frames), _stage(frames, traceback.extract_tb(exc.__traceback__)))
    try:
        exc.verification_where = where
        exc.add_note(f"(verification: raised in {where.text()})")
    except AttributeError:  # an exception type that takes no attributes: the place is still returned
        pass
    return where


def _inside(frame, folders):
    path = Path(frame.f_code.co_filename).resolve()
    return any(path.is_relative_to(folder) for folder in folders)


def _caller(frame):
    return _inside(frame, _CALLERS) and not _inside(frame, (_BACKENDS,))


def _stage(frames, summary):
    """``"stage NAME of CLASS (FILE:LINE)"`` of the innermost stage call in ``frames``, else the innermost frame outside
    the libraries (``"in MODULE.FUNCTION (FILE:LINE), outside the backend's stages"``)."""
    for i in range(len(frames) - 1, 0, -1):
        callee, caller = frames[i], frames[i - 1]
        if callee.f_code.co_name in STAGES and "self" in callee.f_locals and _caller(caller):
            owner = type(callee.f_locals["self"]).__name__
            last = summary[-1]
            return f"stage {callee.f_code.co_name} of {owner} (raised at {Path(last.filename).name}:{last.lineno})"
    for frame, entry in zip(reversed(frames), reversed(summary)):
        if not _inside(frame, _LIBRARIES):
            module = frame.f_globals.get("__name__", "?")
            return (f"in {module}.{frame.f_code.co_name} ({Path(entry.filename).name}:{entry.lineno}), outside the "
                    "backend's stages")
    return None


def _scene(frames):
    """The name of the innermost scene that a frame of ``frames`` holds (module docstring), or ``None``."""
    for frame in reversed(frames):
        local = frame.f_locals
        candidates = [local.get("scene")] + [getattr(local.get(h), "scene", None) for h in _HOLDERS]
        scene = next((c for c in candidates if isinstance(c, Scene)), None)
        if scene is not None:
            return scene.name
    return None

