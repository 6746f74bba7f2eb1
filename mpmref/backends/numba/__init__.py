"""Numba backend: the reference's equations compiled per scene, block-parallel and deterministic."""

from .backend import NumbaBackend

__all__ = ["NumbaBackend"]
