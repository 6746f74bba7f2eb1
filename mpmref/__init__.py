"""mpmref: a readable, verified reference of the Material Point Method.

Public API: :class:`Scene`, :class:`SceneBuilder`, :class:`Simulation` and the errors in
:mod:`mpmref.errors`.
"""

import os
from pathlib import Path


def _default_numba_cache():
    """Point Numba's on-disk cache at a per-user folder (``$XDG_CACHE_HOME`` or ``~/.cache``, then
    ``mpmref/numba``) unless ``NUMBA_CACHE_DIR`` is set; must run before Numba is imported."""
    if "NUMBA_CACHE_DIR" in os.environ:
        return
    folder = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mpmref" / "numba"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return  # an unwritable home: Numba keeps its own default (__pycache__ beside the sources)
    os.environ["NUMBA_CACHE_DIR"] = str(folder)


_default_numba_cache()

from .errors import (  # noqa: E402 - after the cache folder is set
    AllParticlesLeftError, ArgumentError, DomainExitError, InstabilityError, MpmrefError, NonFiniteError, SceneError)
from .scene import Scene, SceneBuilder  # noqa: E402
from .simulation import Simulation  # noqa: E402

__version__ = "0.1.0"
__all__ = ["Scene", "SceneBuilder", "Simulation", "SceneError", "ArgumentError", "InstabilityError", "NonFiniteError",
           "DomainExitError", "AllParticlesLeftError", "MpmrefError"]
