"""Language-neutral exchange with MPM codes that Python cannot import: their start, and what they write.

A code in C++, CUDA, Julia, Fortran or Taichi is checked from its output (``docs/comparing_runs.md``):

* :mod:`.start` writes what such a code needs to start from exactly mpmref's initial state of a scene: the particles
  as ``particles.npz``, ``particles.csv`` and ``particles.vtu`` (with their ids), and ``scene.json``, every number of
  the scene in plain units (``mpmref export SCENE.toml DIR``);
* :mod:`.frames` reads the frames the code wrote (a ``.pvd`` series, ``.vtu``, ``.vtp``, ``.vtk``, ``.npz`` or
  CSV files), matches its particles to the start's by id (or by order), and refuses before any comparison a frame
  that cannot be read, a particle count that changes, a non-finite value or an id that is missing, naming the file
  and the reason.

``mpmref compare`` (:mod:`verification.compare`) judges such frames against an ensemble of the reference.
"""

from .frames import Frame, FrameError, read_frames
from .start import START_FORMAT, export_start, initial_particles, start_record

__all__ = ["Frame", "FrameError", "START_FORMAT", "export_start", "initial_particles", "read_frames", "start_record"]
