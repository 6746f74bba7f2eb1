"""Checkpoints: every particle array plus the run's bookkeeping, in one ``.npz`` written atomically.

Arrays are stored bit for bit, so a run resumed from a checkpoint continues exactly as the original.
"""

import json

import numpy as np

from ..state import Particles
from .atomic import atomic_path


def save_checkpoint(path, particles, meta):
    """Write ``particles`` and the JSON-serialisable ``meta`` dict to ``path`` atomically."""
    arrays = {f"particles.{k}": v for k, v in particles.arrays().items()}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)


def load_checkpoint(path):
    """Read a checkpoint written by :func:`save_checkpoint`; returns ``(particles, meta)``."""
    with np.load(path, allow_pickle=False) as data:
        meta = json.loads(str(data["meta"]))
        arrays = {k.split(".", 1)[1]: data[k] for k in data.files if k.startswith("particles.")}
    return Particles(**arrays), meta
