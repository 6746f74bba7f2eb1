"""mpmref: a readable, verified reference of the Material Point Method.

Public API: :class:`Scene`, :class:`SceneBuilder`, :class:`Simulation` and the errors in
:mod:`mpmref.errors`.
"""

import ctypes
import os
import sys
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


def _threads_that_wait_quietly():
    """Make the Numba backend's worker threads sleep, not spin, while they wait: load the TBB library of the
    ``tbb`` package if this environment has it, so that Numba's threading layer is TBB, and ask any OpenMP
    runtime loaded later for its passive wait policy (Numba's fallback layer).

    On a machine where another process holds a core, OpenMP's default (active) wait spins on it: two threads
    were measured up to 2.3 times slower than one (docs/performance.md, "Threads on a shared machine"). The
    ``tbb`` wheel puts its library in ``<prefix>/lib``, which the dynamic loader does not search in a virtual
    environment, so it is loaded here by path before Numba looks for it. ``NUMBA_THREADING_LAYER`` and
    ``OMP_WAIT_POLICY``, when set, are left as they are; must run before Numba starts its threads.
    """
    os.environ.setdefault("OMP_WAIT_POLICY", "passive")
    if os.environ.get("NUMBA_THREADING_LAYER", "default") not in ("default", "tbb"):
        return
    for library in sorted(Path(sys.prefix, "lib").glob("libtbb.so.1[2-9]*")):
        try:
            ctypes.CDLL(str(library), mode=ctypes.RTLD_GLOBAL)
            return
        except OSError:
            continue


_default_numba_cache()
_threads_that_wait_quietly()

# the package's modules, imported after the cache folder and the threading layer are set
from .errors import (
    AllParticlesLeftError,
    ArgumentError,
    DomainExitError,
    InstabilityError,
    MpmrefError,
    NonFiniteError,
    SceneError,
)
from .run.simulation import Simulation
from .scene import Scene, SceneBuilder

__version__ = "0.1.0"
__all__ = ["Scene", "SceneBuilder", "Simulation", "SceneError", "ArgumentError", "InstabilityError", "NonFiniteError",
           "DomainExitError", "AllParticlesLeftError", "MpmrefError"]
