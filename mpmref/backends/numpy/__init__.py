"""The NumPy reference backend: vectorised over particles, looping only over stencil offsets."""

from .backend import NumpyBackend

__all__ = ["NumpyBackend"]
