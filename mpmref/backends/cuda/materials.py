r"""Materials of the GPU backend: Kirchhoff stress, return map and wave speed of one particle per thread.

The equations are those of :mod:`mpmref.physics.materials` and :mod:`mpmref.physics.plasticity` (their docstrings
give the sources and the symbols); the SVD and polar decomposition are the device functions of
:mod:`mpmref.backends.cuda.svd`. A kernel reads a particle's material from its ``material`` index: :data:`RULES`
maps each material type to the code of its law, and :func:`material_table` lays every material's parameters out
in one row of :data:`PARAMETERS`. Only the laws of the materials a scene declares are compiled in
(:func:`make_materials` takes the set of codes). Adding a material adds its law here: one code, its device
functions and its branch in ``stress`` (and ``return_map`` and ``wave_speed`` where they differ).
"""

import math
from functools import lru_cache
from types import SimpleNamespace

import numpy as np

from ...physics.plasticity import SIGMA_FLOOR
from ..capabilities import material_type
from .launch import device_function, real_types
from .runtime import cuda, load
from .svd import make_svd

#: the code of each material type's law in the kernels
RULES = {"fixed_corotated": 0, "neo_hookean": 1, "fluid": 2, "snow": 3, "sand": 4}
FIXED_COROTATED, NEO_HOOKEAN, FLUID, SNOW, SAND = (RULES[k] for k in ("fixed_corotated", "neo_hookean", "fluid",
                                                                    "snow", "sand"))
#: the columns of a material's row of parameters (unused ones are zero)
PARAMETERS = ("mu", "lam", "rho", "K", "gamma", "hardening", "theta_c", "theta_s", "Jp_min", "Jp_max", "alpha",
              "cohesion")
(MU, LAM, RHO, BULK, GAMMA, HARDENING, THETA_C, THETA_S, JP_MIN, JP_MAX, ALPHA, COHESION) = range(len(PARAMETERS))
#: laws with a return map
PLASTIC = (SNOW, SAND)


def material_table(materials, dtype):
    """``(rules, params)`` of a scene's materials: each material's law code (int64 (k,)) and its parameters in the
    columns of :data:`PARAMETERS` ((k, 12) of ``dtype``)."""
    rules = np.array([RULES[material_type(m)] for m in materials], dtype=np.int64)
    params = np.zeros((len(materials), len(PARAMETERS)), dtype=dtype)
    for row, material in enumerate(materials):
        for col, name in enumerate(PARAMETERS):
            if hasattr(material, name):
                params[row, col] = getattr(material, name)
    return rules, params


def laws(materials):
    """The sorted tuple of the law codes of ``materials`` (what :func:`make_materials` compiles in)."""
    return tuple(sorted({RULES[material_type(m)] for m in materials}))


@lru_cache(maxsize=None)
def make_materials(dtype, dim, present):
    r"""The material device functions in ``dtype`` for ``dim`` × ``dim`` deformation gradients, with the laws of the
    codes ``present`` compiled in. A namespace of:

    * ``stress(rule, prm, F, J, Jp, tau)``: the Kirchhoff stress of a particle of law ``rule`` with parameters
      ``prm`` (its material's row) into the local array ``tau``; ``F`` a local copy of its deformation gradient
      (unread by the fluid), ``J`` and ``Jp`` its volume ratios (unread where the law has none);
    * ``return_map(rule, prm, F, Jp)``: the plastic projection of ``F`` (in place) for snow and sand, returning the
      new :math:`J_P` (``Jp`` itself for the other laws);
    * ``wave_speed(rule, prm, F, J, Jp)``: the current P-wave speed :math:`c_p` in float64 (the CFL rule's);
    * ``load_state(p, F, J, Jp, rule, Fp)``: particle ``p``'s ``F`` copied into the local ``Fp`` and its ``(J, Jp)``,
      from the particle arrays.
    """
    load()
    T, nb = real_types(dtype)
    D = dim
    one, zero, two = T(1.0), T(0.0), T(2.0)
    floor = T(SIGMA_FLOOR)
    svd = make_svd(dtype, dim)
    svd_polar_rotation, svd_signed_svd = svd.polar_rotation, svd.signed_svd
    has = {code: code in present for code in RULES.values()}
    HAS_FC, HAS_NH, HAS_FLUID, HAS_SNOW, HAS_SAND = (has[c] for c in (FIXED_COROTATED, NEO_HOOKEAN, FLUID, SNOW,
                                                                        SAND))

    @device_function
    def det(F):
        r""":math:`\det F` of a 2×2 or 3×3 local array by cofactors."""
        if D == 2:
            return F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
        return (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]) - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
                + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))

    @device_function
    def corotated(F, mu, lam, scale, tau):
        r"""``tau`` = ``scale`` :math:`(2\mu(F - R)F^T + \lambda(J - 1)J\,I)` (fixed-corotated, Stomakhin et al. 2012
        §4), :math:`R` the polar rotation, :math:`J = \det F`."""
        R = cuda.local.array((D, D), nb)
        U = cuda.local.array((D, D), nb)
        Vt = cuda.local.array((D, D), nb)
        sigma = cuda.local.array(D, nb)
        svd_polar_rotation(F, R, U, sigma, Vt)
        J = det(F)
        for a in range(D):
            for b in range(D):
                s = zero
                for c in range(D):
                    s += (F[a, c] - R[a, c]) * F[b, c]
                tau[a, b] = scale * (two * mu * s + (lam * (J - one) * J if a == b else zero))

    @device_function
    def neo_hookean(F, mu, lam, tau):
        r"""``tau`` = :math:`\mu(FF^T - I) + \lambda\ln J\,I` (Bonet & Wood 2008 §6.4.3)."""
        log_J = math.log(det(F))
        for a in range(D):
            for b in range(D):
                s = zero
                for c in range(D):
                    s += F[a, c] * F[b, c]
                tau[a, b] = mu * (s - (one if a == b else zero)) + (lam * log_J if a == b else zero)

    @device_function
    def fluid(J, K, gamma, tau):
        r"""``tau`` = :math:`-pJ\,I`, :math:`p = K(J^{-\gamma} - 1)`: the Tait fluid of Becker & Teschner 2007 §4 and
        Tampubolon et al. 2017 §4.1 (:class:`mpmref.physics.materials.WeaklyCompressibleFluid`)."""
        power = one / J if gamma == one else math.pow(J, -gamma)
        s = -(K * (power - one)) * J
        for a in range(D):
            for b in range(D):
                tau[a, b] = s if a == b else zero

    @device_function
    def compose(U, sigma, Vt, out):
        r"""``out`` = :math:`U\operatorname{diag}(\sigma)V^T`."""
        for a in range(D):
            for b in range(D):
                s = zero
                for c in range(D):
                    s += U[a, c] * sigma[c] * Vt[c, b]
                out[a, b] = s

    @device_function
    def hencky(F, U, eps, Vt):
        r"""``U``, :math:`\epsilon = \ln\max(\sigma, \sigma_{floor})`, ``Vt`` of ``F`` (Klar et al. 2016 §4);
        returns :math:`\operatorname{tr}\epsilon`."""
        svd_signed_svd(F, U, eps, Vt)
        trace = zero
        for a in range(D):
            eps[a] = math.log(max(eps[a], floor))
            trace += eps[a]
        return trace

    @device_function
    def sand(F, mu, lam, tau):
        r"""``tau`` = :math:`U(2\mu\epsilon + \lambda\operatorname{tr}\epsilon\,I)U^T` (Klar et al. 2016 §4)."""
        U = cuda.local.array((D, D), nb)
        Vt = cuda.local.array((D, D), nb)
        eps = cuda.local.array(D, nb)
        trace = hencky(F, U, eps, Vt)
        for a in range(D):
            eps[a] = two * mu * eps[a] + lam * trace
            for b in range(D):
                Vt[a, b] = U[b, a]
        compose(U, eps, Vt, tau)

    @device_function
    def stress(rule, prm, F, J, Jp, tau):
        """The Kirchhoff stress of a particle of law ``rule`` into ``tau`` (see :func:`make_materials`)."""
        if HAS_FLUID and rule == FLUID:
            fluid(J, prm[BULK], prm[GAMMA], tau)
        if HAS_FC and rule == FIXED_COROTATED:
            corotated(F, prm[MU], prm[LAM], one, tau)
        if HAS_SNOW and rule == SNOW:
            corotated(F, prm[MU], prm[LAM], math.exp(prm[HARDENING] * (one - Jp)), tau)
        if HAS_NH and rule == NEO_HOOKEAN:
            neo_hookean(F, prm[MU], prm[LAM], tau)
        if HAS_SAND and rule == SAND:
            sand(F, prm[MU], prm[LAM], tau)

    @device_function
    def snow_return(prm, F, Jp):
        r"""Clamp :math:`\sigma_i` to :math:`[1-\theta_c, 1+\theta_s]` (Stomakhin et al. 2013 §4.1 step 7): ``F`` in
        place (unchanged, bit for bit, when already inside); returns
        :math:`\operatorname{clamp}(J_P \prod\sigma_i / \prod\hat\sigma_i, J_P^{min}, J_P^{max})`."""
        U = cuda.local.array((D, D), nb)
        Vt = cuda.local.array((D, D), nb)
        sigma = cuda.local.array(D, nb)
        svd_signed_svd(F, U, sigma, Vt)
        inside = True
        before, after = one, one
        for a in range(D):
            clamped = min(max(sigma[a], one - prm[THETA_C]), one + prm[THETA_S])
            inside = inside and clamped == sigma[a]
            before *= sigma[a]
            after *= clamped
            sigma[a] = clamped
        if not inside:
            compose(U, sigma, Vt, F)
        return min(max(Jp * (before / after), prm[JP_MIN]), prm[JP_MAX])

    @device_function
    def sand_return(prm, F, Jp):
        r"""Drucker–Prager projection of the Hencky strain with the cohesion shift (Klar et al. 2016 Alg. 2;
        :meth:`mpmref.physics.plasticity.DruckerPragerSand.return_map`): ``F`` in place, returns the new
        :math:`J_P = J_P\,e^{\operatorname{tr}\epsilon - \operatorname{tr}\epsilon^{new}}`."""
        U = cuda.local.array((D, D), nb)
        Vt = cuda.local.array((D, D), nb)
        eps = cuda.local.array(D, nb)
        trace = hencky(F, U, eps, Vt)
        mu, lam, cohesion = prm[MU], prm[LAM], prm[COHESION]
        norm2 = zero
        for a in range(D):
            norm2 += (eps[a] - trace / T(D)) ** 2
        norm = math.sqrt(norm2)
        tr_shifted = trace - T(D) * cohesion
        dgamma = norm + (T(D) * lam + two * mu) / (two * mu) * tr_shifted * prm[ALPHA]
        if not (tr_shifted > zero or dgamma > zero):
            return Jp
        trace_new = zero
        for a in range(D):
            new = cohesion
            if not tr_shifted > zero and norm > zero:
                new = eps[a] - dgamma / norm * (eps[a] - trace / T(D))
            elif not tr_shifted > zero:
                new = eps[a]
            trace_new += new
            eps[a] = math.exp(new)
        compose(U, eps, Vt, F)
        return Jp * math.exp(trace - trace_new)

    @device_function
    def return_map(rule, prm, F, Jp):
        """The plastic projection of ``F`` (in place); returns the new :math:`J_P` (see :func:`make_materials`)."""
        if HAS_SNOW and rule == SNOW:
            return snow_return(prm, F, Jp)
        if HAS_SAND and rule == SAND:
            return sand_return(prm, F, Jp)
        return Jp

    @device_function
    def wave_speed(rule, prm, F, J, Jp):
        r"""The current wave speed :math:`c_p` in float64, by the rules of
        :func:`mpmref.backends.numba.materials.wave_speeds_kernel` (elastic solids and sand, fluid, snow)."""
        mu, lam, rho = float(prm[MU]), float(prm[LAM]), float(prm[RHO])
        if rule == FLUID:
            return math.sqrt(float(prm[GAMMA]) * float(prm[BULK])
                             / (rho * math.pow(max(float(J), 1e-6), float(prm[GAMMA]) - 1.0)))
        if rule == SNOW:
            Jv = max(float(det(F)) * float(Jp), 1e-6)
            return math.sqrt((lam + 2.0 * mu) * math.exp(float(prm[HARDENING]) * (1.0 - float(Jp))) * Jv / rho)
        Jv = max(float(det(F)), 1e-6)
        shear = 4.0 * mu * Jv / (3.0 * rho)
        return math.sqrt(max(shear + (2.0 * mu / 3.0 + lam) * (1.0 - math.log(Jv)) / rho, shear))

    @device_function
    def load_state(p, F, J, Jp, rule, Fp):
        """Particle ``p``'s deformation gradient into the local ``Fp`` (the identity for a fluid, which has none) and
        its ``J``, ``Jp`` (1 where the scene has none), as :func:`stress` and :func:`return_map` take them."""
        for a in range(D):
            for b in range(D):
                Fp[a, b] = F[p, a, b] if rule != FLUID else (one if a == b else zero)
        return (J[p] if J.shape[0] > 0 else one), (Jp[p] if Jp.shape[0] > 0 else one)

    return SimpleNamespace(stress=stress, return_map=return_map, wave_speed=wave_speed, det=det,
                           load_state=load_state)

