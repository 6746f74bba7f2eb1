"""The Numba backend's source digest, a closure constant of its kernel factories' compiled kernels."""

from pathlib import Path

from ..pointwise import source_digest

#: Hash of this backend's source files and of the pointwise functions it calls (:mod:`mpmref.backends.pointwise`).
#: Numba's on-disk cache of a function is invalidated only when *its own* file changes, not when a jitted function it
#: calls from another file does. Each kernel carries this digest as a closure constant, which Numba's cache key
#: includes, so editing any file of the backend or of the pointwise physics recompiles them.
SOURCE_DIGEST = source_digest(Path(__file__).parent, Path(__file__).parent.parent / "pointwise")
