r"""Materials of the Numba backend: Kirchhoff stress and return map, one particle at a time.

The equations are those of :mod:`mpmref.physics.materials` and :mod:`mpmref.physics.plasticity` (see their
docstrings for sources and symbols). Each material has a stress kernel and, if plastic, a return-map
kernel over the index list of its particles; :data:`MATERIAL_ARRAY_KERNELS` maps a material class to them and to
the parameters they take. Adding a material adds its kernels and one entry here.

The singular value and polar decompositions are the fast ones of :mod:`mpmref.backends.numba.svd` (closed form in 2D,
Jacobi sweeps and a Givens QR in 3D; :mod:`mpmref.physics.svd` gives the method and its accuracy), not LAPACK's
``np.linalg.svd``, which cost about 3 µs per particle here. The NumPy reference keeps LAPACK, so the
conformance harness checks these against an independent factorisation. The kernels loop over chunks of
:data:`CHUNK` particles and allocate the decomposition's small work arrays once per chunk.
"""

import numpy as np
from numba import njit, prange

from ...physics.materials import FixedCorotated, NeoHookean, WeaklyCompressibleFluid
from ...physics.plasticity import SIGMA_FLOOR, DruckerPragerSand, SnowPlasticity
from .svd import polar_rotation_into, signed_svd_into

#: particles per chunk of a material kernel's parallel loop (one set of work arrays per chunk)
CHUNK = 64


@njit(cache=True)
def n_chunks(n):
    """Number of :data:`CHUNK`-sized chunks covering ``n`` particles."""
    return (n + CHUNK - 1) // CHUNK


@njit(cache=True)
def work_arrays(d, dtype):
    """Work arrays of one chunk: ``R``, ``U``, ``sigma``, ``Vt`` for :mod:`mpmref.backends.numba.svd`, and a second
    length-``d`` vector."""
    return (np.empty((d, d), dtype), np.empty((d, d), dtype), np.empty(d, dtype), np.empty((d, d), dtype),
            np.empty(d, dtype))


@njit(cache=True, inline="always")
def det_small(F):
    r""":math:`\det F` of a 2×2 or 3×3 matrix by cofactors (Laplace expansion along the first row)."""
    if F.shape[0] == 2:
        return F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
    return (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1])
            - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
            + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))


@njit(cache=True, inline="always")
def corotated_stress_into(F, mu, lam, scale, out, R, U, sigma, Vt):
    r"""``out = scale * (2 mu (F - R) F^T + lam (J - 1) J I)`` (fixed-corotated Kirchhoff stress,
    Stomakhin et al. 2012 §4), :math:`R = UV^T` the polar rotation (:func:`.svd.polar_rotation_into`: closed
    form in 2D), :math:`J = \det F`. ``R``, ``U``, ``sigma``, ``Vt`` are work arrays."""
    polar_rotation_into(F, R, U, sigma, Vt)
    J = det_small(F)
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
    n = idx.shape[0]
    for chunk in prange(n_chunks(n)):
        R, U, sigma, Vt, _ = work_arrays(F.shape[1], F.dtype)
        for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            p = idx[k]
            corotated_stress_into(F[p], mu, lam, 1.0, tau[p], R, U, sigma, Vt)


@njit(cache=True, inline="always")
def neo_hookean_stress_into(F, mu, lam, out):
    r"""``out`` = :math:`\mu(FF^T - I) + \lambda \ln J\, I` (Bonet & Wood 2008 §6.4.3), :math:`J = \det F`."""
    d = F.shape[0]
    log_J = np.log(det_small(F))
    for a in range(d):
        for b in range(d):
            s = 0.0
            for c in range(d):
                s += F[a, c] * F[b, c]
            out[a, b] = mu * (s - (1.0 if a == b else 0.0)) + (lam * log_J if a == b else 0.0)


@njit(parallel=True, cache=True)
def neo_hookean_stress(F, Jp, idx, mu, lam, tau):
    """Neo-Hookean Kirchhoff stress (:func:`neo_hookean_stress_into`) of the particles ``idx``."""
    for k in prange(idx.shape[0]):
        p = idx[k]
        neo_hookean_stress_into(F[p], mu, lam, tau[p])


@njit(cache=True, inline="always")
def fluid_stress_into(J, K, gamma, out):
    r"""``out`` = :math:`\tau = -p J\, I`, :math:`p = K(J^{-\gamma} - 1)` (Tait fluid) at volume ratio ``J``."""
    d = out.shape[0]
    s = -(K * ((1.0 / J if gamma == 1.0 else J ** (-gamma)) - 1.0)) * J
    for a in range(d):
        for b in range(d):
            out[a, b] = s if a == b else 0.0


@njit(parallel=True, cache=True)
def fluid_stress(J, idx, K, gamma, tau):
    """Fluid Kirchhoff stress (:func:`fluid_stress_into`) of the particles ``idx``."""
    for k in prange(idx.shape[0]):
        p = idx[k]
        fluid_stress_into(J[p], K, gamma, tau[p])


@njit(parallel=True, cache=True)
def snow_stress(F, Jp, idx, mu, lam, hardening, tau):
    r""":math:`\tau = e^{\xi(1 - J_P)}\,\tau_{corotated}(F_E)` (Stomakhin et al. 2013 §5) of the particles ``idx``."""
    n = idx.shape[0]
    for chunk in prange(n_chunks(n)):
        R, U, sigma, Vt, _ = work_arrays(F.shape[1], F.dtype)
        for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            p = idx[k]
            corotated_stress_into(F[p], mu, lam, np.exp(hardening * (1.0 - Jp[p])), tau[p], R, U, sigma, Vt)


@njit(parallel=True, cache=True)
def snow_return_map(F, Jp, idx, theta_c, theta_s, Jp_min, Jp_max):
    r"""Clamp :math:`\sigma_i` to :math:`[1-\theta_c, 1+\theta_s]` and move the excess into :math:`J_P`
    (Stomakhin et al. 2013 §4.1 step 7), in place; particles already inside keep ``F`` bit for bit.

    :math:`U\hat\Sigma V^T` is unique even where singular values repeat (equal :math:`\sigma_i` clamp to
    equal :math:`\hat\sigma_i`), so the fast SVD's choice of :math:`U, V` there does not matter."""
    d = F.shape[1]
    n = idx.shape[0]
    for chunk in prange(n_chunks(n)):
        _, U, sigma, Vt, _ = work_arrays(d, F.dtype)
        for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            p = idx[k]
            signed_svd_into(F[p], U, sigma, Vt)
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


@njit(cache=True, inline="always")
def compose_into(U, sigma, Vt, out):
    r"""``out = U diag(sigma) Vt``."""
    d = out.shape[0]
    for a in range(d):
        for b in range(d):
            s = 0.0
            for c in range(d):
                s += U[a, c] * sigma[c] * Vt[c, b]
            out[a, b] = s


@njit(cache=True, inline="always")
def hencky_strain_into(F, U, eps, Vt):
    r"""``U``, :math:`\epsilon = \ln\max(\sigma, \sigma_{floor})` into ``eps``, ``Vt`` (Klar et al. 2016 §4);
    returns :math:`\operatorname{tr}\epsilon`."""
    signed_svd_into(F, U, eps, Vt)
    trace = 0.0
    for a in range(F.shape[0]):
        eps[a] = np.log(max(eps[a], SIGMA_FLOOR))
        trace += eps[a]
    return trace


@njit(cache=True, inline="always")
def sand_stress_into(F, mu, lam, out, Ut, U, eps, Vt):
    r"""``out`` = :math:`\tau = U(2\mu\epsilon + \lambda\,\mathrm{tr}\,\epsilon\, I)U^T` (Klar et al. 2016 §4).

    Unique where singular values repeat (equal :math:`\sigma_i`, equal principal stresses). ``Ut``, ``U``,
    ``eps``, ``Vt`` are work arrays."""
    d = F.shape[0]
    trace = hencky_strain_into(F, U, eps, Vt)
    for a in range(d):
        eps[a] = 2.0 * mu * eps[a] + lam * trace
        for b in range(d):
            Ut[a, b] = U[b, a]
    compose_into(U, eps, Ut, out)


@njit(parallel=True, cache=True)
def sand_stress(F, Jp, idx, mu, lam, tau):
    """Drucker-Prager sand's Kirchhoff stress (:func:`sand_stress_into`) of the particles ``idx``."""
    d = F.shape[1]
    n = idx.shape[0]
    for chunk in prange(n_chunks(n)):
        Ut, U, eps, Vt, _ = work_arrays(d, F.dtype)
        for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            p = idx[k]
            sand_stress_into(F[p], mu, lam, tau[p], Ut, U, eps, Vt)


@njit(parallel=True, cache=True)
def sand_return_map(F, Jp, idx, mu, lam, alpha, cohesion):
    r"""Drucker–Prager projection of the Hencky strain with the cohesion shift (Klar et al. 2016 Alg. 2; see
    :meth:`mpmref.physics.plasticity.DruckerPragerSand.return_map`), in place.

    :math:`U e^{\epsilon^{new}} V^T` is unique where singular values repeat: the projection maps equal
    strains to equal strains."""
    d = F.shape[1]
    n = idx.shape[0]
    for chunk in prange(n_chunks(n)):
        _, U, eps, Vt, eps_new = work_arrays(d, F.dtype)
        for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            p = idx[k]
            trace = hencky_strain_into(F[p], U, eps, Vt)
            norm2 = 0.0
            for a in range(d):
                norm2 += (eps[a] - trace / d) ** 2
            norm = np.sqrt(norm2)
            tr_shifted = trace - d * cohesion
            dgamma = norm + (d * lam + 2.0 * mu) / (2.0 * mu) * tr_shifted * alpha
            if tr_shifted > 0:
                for a in range(d):
                    eps_new[a] = cohesion
            elif dgamma > 0:
                for a in range(d):
                    eps_new[a] = eps[a] - dgamma / norm * (eps[a] - trace / d) if norm > 0 else eps[a]
            else:
                continue
            trace_new = 0.0
            for a in range(d):
                trace_new += eps_new[a]
                eps_new[a] = np.exp(eps_new[a])
            compose_into(U, eps_new, Vt, F[p])
            Jp[p] = Jp[p] * np.exp(trace - trace_new)


def _elastic(kernel):
    return lambda m, F, J, Jp, idx, tau: kernel(F, Jp, idx, m.mu, m.lam, tau)


#: material class -> (stress(material, F, J, Jp, idx, tau), return_map(material, F, Jp, idx) or None)
MATERIAL_ARRAY_KERNELS = {
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


# --------------------------------------------------------------------------- wave speeds (step limits)
#: wave-speed rules of :func:`wave_speeds_kernel`, per material class (the ``wave_speeds`` method each follows)
WAVE_RULE = {FixedCorotated: 0, NeoHookean: 0, DruckerPragerSand: 0, WeaklyCompressibleFluid: 1, SnowPlasticity: 2}


def wave_parameters(materials):
    r"""``(rules, params)`` of :func:`wave_speeds_kernel` for a scene's materials: each material's rule
    (0 elastic, 1 fluid, 2 snow) and the constant factors of its wave speed, taken out of the per-particle loop:
    :math:`(4\mu/(3\rho_0),\ (2\mu/3 + \lambda)/\rho_0)` for the elastic solids and sand,
    :math:`(\gamma K/\rho_0,\ \gamma - 1)` for a fluid, :math:`((\lambda + 2\mu)/\rho_0,\ \xi)` for snow
    (:math:`\xi` the hardening)."""
    rules = np.array([WAVE_RULE[type(m)] for m in materials], dtype=np.int64)
    params = np.zeros((len(materials), 2), dtype=np.float64)
    for i, m in enumerate(materials):
        if isinstance(m, WeaklyCompressibleFluid):
            params[i] = m.gamma * m.K / m.rho, m.gamma - 1.0
        elif WAVE_RULE[type(m)] == 2:
            params[i] = (m.lam + 2.0 * m.mu) / m.rho, m.hardening
        else:
            params[i] = 4.0 * m.mu / (3.0 * m.rho), (2.0 * m.mu / 3.0 + m.lam) / m.rho
    return rules, params


@njit(parallel=True, cache=True)
def wave_speeds_kernel(F, J, Jp, material, idx, rules, params, out):
    r"""Current wave speed :math:`c_p` (the CFL rule's) of the particles ``idx`` into ``out``, one particle at a
    time, by its material's rule (the ``wave_speeds`` methods of :mod:`mpmref.physics.materials` and
    :mod:`mpmref.physics.plasticity`, which give the sources), with the factors of :func:`wave_parameters`:

    * elastic solids and sand (rule 0): :math:`c^2 = 4\mu J/(3\rho_0) + (2\mu/3 + \lambda)(1 - \ln J)/\rho_0`,
      at least the shear part, :math:`J = \max(\det F, 10^{-6})`;
    * fluid (rule 1): :math:`c^2 = \gamma K / (\rho_0 J^{\gamma - 1})`, :math:`J \ge 10^{-6}`;
    * snow (rule 2): :math:`c^2 = (\lambda + 2\mu)\, e^{\xi(1 - J_P)} J / \rho_0`,
      :math:`J = \max(\det F_E\, J_P, 10^{-6})`.

    In parallel over chunks of :data:`CHUNK` particles (asynchronous stepping asks at every step boundary).
    """
    n = idx.shape[0]
    for chunk in prange(n_chunks(n)):
        for k in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            out[k] = wave_speed_of(F, J, Jp, material, idx[k], rules, params)


@njit(cache=True, inline="always")
def wave_speed_of(F, J, Jp, material, p, rules, params):
    """The wave speed of particle ``p`` (:func:`wave_speeds_kernel`)."""
    m = material[p]
    rule = rules[m]
    a, b = params[m, 0], params[m, 1]
    if rule == 1:
        return np.sqrt(a / max(J[p], 1e-6) ** b)
    if rule == 2:
        Jv = max(det_small(F[p]) * Jp[p], 1e-6)
        return np.sqrt(a * np.exp(b * (1.0 - Jp[p])) * Jv)
    Jv = max(det_small(F[p]), 1e-6)
    shear = a * Jv
    return np.sqrt(max(shear + b * (1.0 - np.log(Jv)), shear))


# --------------------------------------------------------------------------- fluid stress inside P2G
def fluid_parameters(materials):
    r"""``(k, 2)`` float64: :math:`(K, \gamma)` of each of a scene's materials that is a weakly compressible
    fluid (zeros for the others), for P2G's own fluid stress (:func:`mpmref.backends.numba.transfers2d.p2g_kernel`)."""
    params = np.zeros((len(materials), 2), dtype=np.float64)
    for i, material in enumerate(materials):
        if isinstance(material, WeaklyCompressibleFluid):
            params[i] = material.K, material.gamma
    return params
