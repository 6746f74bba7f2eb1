r"""The signed SVD and polar decomposition of one matrix, compiled for the CPU and allocating its results: the
pointwise functions of :mod:`mpmref.backends.pointwise.svd` (what the material kernels run) for callers in Python."""

import numpy as np
from numba import njit

from ..pointwise import svd


@njit(cache=True)
def signed_svd(F):
    r"""Signed SVD of one (d, d) ``F``: ``U``, ``sigma``, ``Vt`` (as :func:`mpmref.physics.materials.signed_svd`
    for one matrix)."""
    d = F.shape[0]
    U = np.empty((d, d), F.dtype)
    sigma = np.empty(d, F.dtype)
    Vt = np.empty((d, d), F.dtype)
    svd.signed_svd(F, U, sigma, Vt)
    return U, sigma, Vt


@njit(cache=True)
def polar_rotation(F):
    r"""Rotation :math:`R` of the polar decomposition of one (d, d) ``F``."""
    d = F.shape[0]
    R = np.empty((d, d), F.dtype)
    U = np.empty((d, d), F.dtype)
    sigma = np.empty(d, F.dtype)
    Vt = np.empty((d, d), F.dtype)
    svd.polar_rotation(F, R, U, sigma, Vt)
    return R
