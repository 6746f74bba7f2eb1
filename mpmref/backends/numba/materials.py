r"""Materials of the Numba backend: Kirchhoff stress and return map, one particle at a time.

The equations are those of :mod:`mpmref.physics.materials` and :mod:`mpmref.physics.plasticity` (see their
docstrings for sources and symbols). Each material has a stress kernel and, if plastic, a return-map
kernel over the index list of its particles; :data:`KERNELS` maps a material class to them and to the
parameters they take. Adding a material adds its kernels and one entry here.
"""

import numpy as np
from numba import njit, prange

from ...physics.materials import FixedCorotated, NeoHookean, WeaklyCompressibleFluid
from ...physics.plasticity import SIGMA_FLOOR, DruckerPragerSand, SnowPlasticity


@njit(cache=True)
def signed_svd(F):
    r"""SVD :math:`F = U \Sigma V^T` with proper rotations (as :func:`mpmref.physics.materials.signed_svd`)."""
    U, sigma, Vt = np.linalg.svd(F)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        d = F.shape[0]
        for a in range(d):
            U[a, d - 1] = -U[a, d - 1]
        sigma[d - 1] = -sigma[d - 1]
    return U, sigma, Vt


@njit(cache=True)
def corotated_stress_into(F, mu, lam, scale, out):
    r"""``out = scale * (2 mu (F - R) F^T + lam (J - 1) J I)`` (fixed-corotated Kirchhoff stress,
    Stomakhin et al. 2012 §4), :math:`R = UV^T`, :math:`J = \det F`."""
    U, _, Vt = signed_svd(F)
    R = U @ Vt
    J = np.linalg.det(F)
    d = F.shape[0]
    for a in range(d):
        for b in range(d):
            s = 0.0
            for c in range(d):
                s += (F[a, c] - R[a, c]) * F[b, c]
            out[a, b] = scale * (2.0 * mu * s + (lam * (J - 1.0) * J if a == b else 0.0))


@njit(parallel=True, cache=True)
def fixed_corotated_stress(F, Jp, idx, mu, lam, tau):
    """Fixed-corotated Kirchhoff stress of the particles ``idx``."""
    for k in prange(idx.shape[0]):
        p = idx[k]
        corotated_stress_into(np.ascontiguousarray(F[p]), mu, lam, 1.0, tau[p])


@njit(parallel=True, cache=True)
def neo_hookean_stress(F, Jp, idx, mu, lam, tau):
    r""":math:`\tau = \mu(FF^T - I) + \lambda \ln J\, I` (Bonet & Wood 2008 §6.4.3) of the particles ``idx``."""
    d = F.shape[1]
    for k in prange(idx.shape[0]):
        p = idx[k]
        log_J = np.log(np.linalg.det(np.ascontiguousarray(F[p])))
        for a in range(d):
            for b in range(d):
                s = 0.0
                for c in range(d):
                    s += F[p, a, c] * F[p, b, c]
                tau[p, a, b] = mu * (s - (1.0 if a == b else 0.0)) + (lam * log_J if a == b else 0.0)


@njit(parallel=True, cache=True)
def fluid_stress(J, idx, K, gamma, tau):
    r""":math:`\tau = -p J\, I`, :math:`p = K(J^{-\gamma} - 1)` (Tait fluid) of the particles ``idx``."""
    d = tau.shape[1]
    for k in prange(idx.shape[0]):
        p = idx[k]
        s = -(K * (J[p] ** (-gamma) - 1.0)) * J[p]
        for a in range(d):
            for b in range(d):
                tau[p, a, b] = s if a == b else 0.0


@njit(parallel=True, cache=True)
def snow_stress(F, Jp, idx, mu, lam, hardening, tau):
    r""":math:`\tau = e^{\xi(1 - J_P)}\,\tau_{corotated}(F_E)` (Stomakhin et al. 2013 §5) of the particles ``idx``."""
    for k in prange(idx.shape[0]):
        p = idx[k]
        corotated_stress_into(np.ascontiguousarray(F[p]), mu, lam, np.exp(hardening * (1.0 - Jp[p])), tau[p])


@njit(parallel=True, cache=True)
def snow_return_map(F, Jp, idx, theta_c, theta_s, Jp_min, Jp_max):
    r"""Clamp :math:`\sigma_i` to :math:`[1-\theta_c, 1+\theta_s]` and move the excess into :math:`J_P`
    (Stomakhin et al. 2013 §4.1 step 7), in place; particles already inside keep ``F`` bit for bit."""
    d = F.shape[1]
    for k in prange(idx.shape[0]):
        p = idx[k]
        U, sigma, Vt = signed_svd(np.ascontiguousarray(F[p]))
        inside = True
        before, after = 1.0, 1.0
        for a in range(d):
            clamped = min(max(sigma[a], 1.0 - theta_c), 1.0 + theta_s)
            inside = inside and clamped == sigma[a]
            before *= sigma[a]
            after *= clamped
            sigma[a] = clamped
        if not inside:
            compose_into(U, sigma, Vt, F[p])
        Jp[p] = min(max(Jp[p] * (before / after), Jp_min), Jp_max)


@njit(cache=True)
def compose_into(U, sigma, Vt, out):
    r"""``out = U diag(sigma) Vt``."""
    d = out.shape[0]
    for a in range(d):
        for b in range(d):
            s = 0.0
            for c in range(d):
                s += U[a, c] * sigma[c] * Vt[c, b]
            out[a, b] = s


@njit(cache=True)
def hencky_strain(F):
    r"""``U``, :math:`\ln\max(\sigma, \sigma_{floor})`, ``Vt`` (Klar et al. 2016 §4)."""
    U, sigma, Vt = signed_svd(F)
    return U, np.log(np.maximum(sigma, SIGMA_FLOOR)), Vt


@njit(parallel=True, cache=True)
def sand_stress(F, Jp, idx, mu, lam, tau):
    r""":math:`\tau = U(2\mu\epsilon + \lambda\,\mathrm{tr}\,\epsilon\, I)U^T` (Klar et al. 2016 §4) of ``idx``."""
    for k in prange(idx.shape[0]):
        p = idx[k]
        U, eps, _ = hencky_strain(np.ascontiguousarray(F[p]))
        principal = 2.0 * mu * eps + lam * np.sum(eps)
        compose_into(U, principal, U.T.copy(), tau[p])


@njit(parallel=True, cache=True)
def sand_return_map(F, Jp, idx, mu, lam, alpha, cohesion):
    r"""Drucker–Prager projection of the Hencky strain with the cohesion shift (Klar et al. 2016 Alg. 2; see
    :meth:`mpmref.physics.plasticity.DruckerPragerSand.return_map`), in place."""
    d = F.shape[1]
    for k in prange(idx.shape[0]):
        p = idx[k]
        U, eps, Vt = hencky_strain(np.ascontiguousarray(F[p]))
        trace = np.sum(eps)
        dev = eps - trace / d
        norm = np.sqrt(np.sum(dev**2))
        tr_shifted = trace - d * cohesion
        dgamma = norm + (d * lam + 2.0 * mu) / (2.0 * mu) * tr_shifted * alpha
        if tr_shifted > 0:
            eps_new = np.full(d, cohesion)
        elif dgamma > 0:
            eps_new = eps - dgamma / norm * dev if norm > 0 else eps.copy()
        else:
            continue
        compose_into(U, np.exp(eps_new), Vt, F[p])
        Jp[p] = Jp[p] * np.exp(trace - np.sum(eps_new))


def _elastic(kernel):
    return lambda m, F, J, Jp, idx, tau: kernel(F, Jp, idx, m.mu, m.lam, tau)


#: material class -> (stress(material, F, J, Jp, idx, tau), return_map(material, F, Jp, idx) or None)
KERNELS = {
    FixedCorotated: (_elastic(fixed_corotated_stress), None),
    NeoHookean: (_elastic(neo_hookean_stress), None),
    WeaklyCompressibleFluid: (lambda m, F, J, Jp, idx, tau: fluid_stress(J, idx, m.K, m.gamma, tau), None),
    SnowPlasticity: (
        lambda m, F, J, Jp, idx, tau: snow_stress(F, Jp, idx, m.mu, m.lam, m.hardening, tau),
        lambda m, F, Jp, idx: snow_return_map(F, Jp, idx, m.theta_c, m.theta_s, m.Jp_min, m.Jp_max),
    ),
    DruckerPragerSand: (
        _elastic(sand_stress),
        lambda m, F, Jp, idx: sand_return_map(F, Jp, idx, m.mu, m.lam, m.alpha, m.cohesion),
    ),
}
