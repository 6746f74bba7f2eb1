"""The Numba backend's source digest, a closure constant of its kernel factories' compiled kernels."""

import hashlib
from pathlib import Path


def _source_digest():
    """Hash of this backend's source files.

    Numba's on-disk cache of a function is invalidated only when *its own* file changes, not when a jitted
    function it calls from another file does. Each transfer kernel carries this digest as a closure
    constant, which Numba's cache key includes, so editing any file of the backend recompiles them.
    """
    h = hashlib.sha256()
    for path in sorted(Path(__file__).parent.rglob("*.py")):
        h.update(path.read_bytes())
    return h.hexdigest()


SOURCE_DIGEST = _source_digest()
