r"""Candidates with a bug of the kind that hides at the extremes, each a delegate of the NumPy reference with one
stage changed (docs/conformance.md, "Extremes"): random states near the scene's scales pass them, the extreme cases
catch them, and ``mpmref conformance search`` finds them (tests/test_extremes.py, tests/test_search.py). Importable by
name (``planted_extremes:QuirkySvd``) when ``tests/`` is on the path.

* :class:`QuirkySvd`: a 2D SVD that, where the symmetric polar factor :math:`S = R^TF` has :math:`|S_{01}| <
  10^{-5}`, returns its diagonal as the singular values (with :math:`U = R`, :math:`V = I`), so that
  :math:`\prod_i\sigma_i = \det F + S_{01}^2`: the behaviour described of Taichi's 2D ``ti.svd`` (written here from that
  description), used as the 88-line programs use it, :math:`J = \prod_i\sigma_i` in the fixed-corotated stress.
* :class:`IntBaseNode`: the base node truncated with ``int()`` in a frame anchored at world zero (as a sparse grid
  keyed by integer coordinates is), which is ``floor`` for positive coordinates only.
* :class:`SkipsAtYieldSurface`: a snow return map that takes the states within 1e-6 (relative) of the yield surface
  as on it, and leaves them unprojected.
* :class:`GradientSignOnFace`: the linear hat's gradient taken as :math:`-1` where the distance to the node is
  positive and :math:`+1` otherwise, so that a particle exactly on a node line gets the wrong sign there (its weights
  belong to the cell above, its gradient to the cell below, and :math:`\sum_i \nabla w_{ip} \ne 0`).
"""

from dataclasses import dataclass

import numpy as np

from mpmref.backends.numpy import NumpyBackend
from mpmref.physics.kernels import LinearHat
from mpmref.physics.materials import FixedCorotated, signed_svd
from mpmref.physics.plasticity import SnowPlasticity
from mpmref.physics.svd import polar_2d

#: below this :math:`|S_{01}|` the quirky SVD takes the diagonal of :math:`S` (the threshold described of ti.svd)
QUIRK_THRESHOLD = 1e-5
#: the relative band around the yield surface that :class:`SkipsAtYieldSurface` leaves unprojected
YIELD_TOLERANCE = 1e-6


def quirky_svd(F):
    r"""Signed SVD of 2D ``F`` (n, 2, 2), but where :math:`|S_{01}|` of the polar factor :math:`S = R^TF` is below
    :data:`QUIRK_THRESHOLD`: :math:`U = R`, :math:`\sigma = (S_{00}, S_{11})`, :math:`V = I`."""
    U, sigma, Vt = signed_svd(F)
    R, S = polar_2d(F)
    quirk = np.abs(S[:, 0, 1]) < QUIRK_THRESHOLD
    U[quirk], Vt[quirk] = R[quirk], np.eye(2)
    sigma[quirk] = np.stack([S[quirk, 0, 0], S[quirk, 1, 1]], axis=-1)
    return U, sigma, Vt


def corotated_stress(mu, lam, F):
    r"""Fixed-corotated Kirchhoff stress with the quirky SVD, as the 88-line programs write it:
    :math:`\tau = 2\mu(F - UV^T)F^T + \lambda J(J - 1) I`, :math:`J = \prod_i \sigma_i`."""
    U, sigma, Vt = quirky_svd(F)
    J = np.prod(sigma, axis=1)
    return 2.0 * mu[:, None, None] * (F - U @ Vt) @ F.transpose(0, 2, 1) + (lam * J * (J - 1.0))[:, None, None] * \
        np.eye(2)


class QuirkySvd(NumpyBackend):
    """The reference whose 2D fixed-corotated and snow stresses, and snow's return map, use :func:`quirky_svd`."""

    def stress(self, particles):
        tau = super().stress(particles)
        if self.scene.dim != 2:
            return tau
        for index, m in enumerate(self.scene.material_list):
            rows = np.flatnonzero(particles.material == index)
            if isinstance(m, (FixedCorotated, SnowPlasticity)) and rows.size:
                hardening = m.hardening_factor(particles.Jp[rows]) if isinstance(m, SnowPlasticity) else 1.0
                mu, lam = m.mu * np.ones(rows.size) * hardening, m.lam * np.ones(rows.size) * hardening
                tau[rows] = corotated_stress(mu, lam, particles.F[rows])
        return tau

    def return_map(self, particles):
        new = super().return_map(particles)
        if self.scene.dim != 2 or new.Jp is None:  # no plastic material: nothing to project
            return new
        F, Jp = new.F.copy(), new.Jp.copy()
        for index, m in enumerate(self.scene.material_list):
            rows = np.flatnonzero(particles.material == index)
            if isinstance(m, SnowPlasticity) and rows.size:
                F[rows], Jp[rows] = snow_return_map(m, particles.F[rows], particles.Jp[rows])
        return new.with_(F=F, Jp=Jp)


def snow_return_map(material, F, Jp):
    """Snow's return map (:meth:`mpmref.physics.plasticity.SnowPlasticity.return_map`) with :func:`quirky_svd`."""
    U, sigma, Vt = quirky_svd(F)
    clamped = np.clip(sigma, 1.0 - material.theta_c, 1.0 + material.theta_s)
    inside = np.all(clamped == sigma, axis=1)
    F_new = np.where(inside[:, None, None], F, (U * clamped[:, None, :]) @ Vt)
    ratio = np.prod(sigma, axis=1) / np.prod(clamped, axis=1)
    return F_new, np.clip(Jp * ratio, material.Jp_min, material.Jp_max)


@dataclass(frozen=True)
class TruncatedBase:
    """A kernel whose base node is ``int(xi - shift + k) - k``, ``k`` the world lattice index of the grid's origin
    (``floor(origin / dx)``): the truncation of a coordinate anchored at world zero, which is the floor where that
    coordinate is positive only."""

    kernel: object
    lattice: np.ndarray

    def __getattr__(self, name):
        return getattr(self.kernel, name)

    def base_node(self, xi):
        return np.trunc(xi - self.kernel.base_shift + self.lattice).astype(np.int64) - self.lattice.astype(np.int64)

    def weights(self, fx):
        return self.kernel.weights(fx)


class IntBaseNode(NumpyBackend):
    """The reference whose stencils (P2G, G2P and the step's) take the base node of :class:`TruncatedBase`."""

    def __init__(self, scene):
        super().__init__(scene)
        self.kernel = TruncatedBase(scene.kernel, np.floor(scene.grid.origin / scene.grid.dx))


class SkipsAtYieldSurface(NumpyBackend):
    """The reference whose snow return map leaves unprojected every particle whose singular values lie within
    :data:`YIELD_TOLERANCE` (relative) of the yield surface's bounds, taking them as on it."""

    def return_map(self, particles):
        new = super().return_map(particles)
        keep = np.zeros(particles.n, dtype=bool)
        for index, m in enumerate(self.scene.material_list):
            if isinstance(m, SnowPlasticity):
                _, sigma, _ = signed_svd(particles.F)
                lo, hi = (1.0 - m.theta_c) * (1.0 - YIELD_TOLERANCE), (1.0 + m.theta_s) * (1.0 + YIELD_TOLERANCE)
                keep |= (particles.material == index) & np.all((sigma >= lo) & (sigma <= hi), axis=1)
        return new.with_(F=np.where(keep[:, None, None], particles.F, new.F), Jp=np.where(keep, particles.Jp, new.Jp))


@dataclass(frozen=True)
class SignedHat(LinearHat):
    """The linear hat with its gradient from the sign of the distance :math:`r` to each node, :math:`-1` for
    :math:`r > 0` and :math:`+1` otherwise: at :math:`r = 0` (a particle on the node line) the sign of the cell
    below."""

    def weights(self, fx):
        w, _ = super().weights(fx)
        dw = np.stack([np.where(fx > 0, -1.0, 1.0), np.ones_like(fx)], axis=-1)
        return w, dw


class GradientSignOnFace(NumpyBackend):
    """The reference whose linear kernel is :class:`SignedHat` (the other kernels are the reference's)."""

    def __init__(self, scene):
        super().__init__(scene)
        if isinstance(scene.kernel, LinearHat):
            self.kernel = SignedHat()


#: the planted bugs, by name
PLANTED = {"quirky-svd": QuirkySvd, "int-base-node": IntBaseNode, "skips-at-yield-surface": SkipsAtYieldSurface,
           "gradient-sign-on-face": GradientSignOnFace}
