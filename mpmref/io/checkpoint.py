"""Checkpoints: the whole :class:`~mpmref.state.State` plus the run's bookkeeping, in one ``.npz`` written atomically.

Arrays are stored bit for bit (particles with their ids and CPIC tags, the stepper's own arrays and the rigid
bodies' state), so a run resumed
from a checkpoint continues exactly as the original, synchronous or asynchronous.
"""

import json

import numpy as np

from ..rigid.dynamics import RigidState
from ..state import Particles, State
from .atomic import atomic_path


def save_checkpoint(path, state, meta):
    """Write ``state`` and the JSON-serialisable ``meta`` dict to ``path`` atomically."""
    arrays = {f"particles.{k}": v for k, v in state.particles.arrays().items()}
    arrays.update({f"stepper.{k}": np.asarray(v) for k, v in state.stepper.items()})
    if state.rigid is not None:
        arrays.update({f"rigid.{k}": v for k, v in state.rigid.arrays().items()})
    meta = {**meta, "clock": state.clock()}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)


def load_checkpoint(path):
    """Read a checkpoint written by :func:`save_checkpoint`; returns ``(state, meta)``."""
    with np.load(path, allow_pickle=False) as data:
        meta = json.loads(str(data["meta"]))
        particles = {k.split(".", 1)[1]: data[k] for k in data.files if k.startswith("particles.")}
        stepper = {k.split(".", 1)[1]: data[k] for k in data.files if k.startswith("stepper.")}
        rigid = {k.split(".", 1)[1]: data[k] for k in data.files if k.startswith("rigid.")}
    return State(particles=Particles(**particles), stepper=stepper, rigid=RigidState(**rigid) if rigid else None,
                 **meta["clock"]), meta
