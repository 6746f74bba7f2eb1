r"""The material laws of the compiled backends, one particle at a time: Kirchhoff stress, return map and wave speed.

The equations are those of :mod:`mpmref.physics.materials` and :mod:`mpmref.physics.plasticity` (their docstrings give
the sources and every symbol). A material names its law's functions here in its declaration, next to its reference
class (:class:`mpmref.physics.materials.CompiledLaw`, the class attribute ``compiled``), with the parameters they
read, in order: its *parameter row* ``prm``, float64. Every law has the same three signatures, so that a kernel calls
any of them alike:

* ``stress(prm, F, J, Jp, tau, work)``: the Kirchhoff stress of one particle into ``tau`` (d, d), from its
  deformation gradient ``F`` (d, d; unread by a law of :math:`J`), volume ratio ``J`` and plastic volume ratio
  ``Jp`` (1 where the scene has none);
* ``return_map(prm, F, Jp, work)``: the plastic projection of ``F``, in place; returns the new :math:`J_P`;
* ``wave_speed(prm, F, J, Jp)``: the particle's current wave speed :math:`c_p` (the CFL rule's), in float64.

``work`` is a (:data:`WORK`, d, d) array of the run's dtype for the decompositions: three matrices and, in its last
matrix's rows, vectors. Stress and return map compute in the dtype of ``tau`` and ``F`` (the parameters converted to
it); the wave speed in float64, as the reference does.
"""

import hashlib
import importlib
import inspect
import math
from types import SimpleNamespace

import numpy as np

from ...physics.plasticity import SIGMA_FLOOR
from . import pointwise
from .svd import compose, determinant, polar_rotation, signed_svd

#: matrices of the ``work`` array every law takes
WORK = 4
#: the smallest volume ratio the wave speeds take (the reference's clip)
J_FLOOR = 1e-6


# ------------------------------------------------------------------------------------------------- stresses
@pointwise(inline=True)
def corotated_into(F, mu, lam, scale, tau, work):
    r"""``tau`` = ``scale`` :math:`(2\mu(F - R)F^T + \lambda(J - 1)J\,I)` (fixed-corotated, Stomakhin et al. 2012 §4),
    :math:`R` the polar rotation (:func:`mpmref.backends.pointwise.svd.polar_rotation`), :math:`J = \det F`."""
    real = tau.dtype.type
    polar_rotation(F, work[0], work[1], work[3, 0], work[2])
    R = work[0]
    J = determinant(F)
    d = F.shape[0]
    for a in range(d):
        for b in range(d):
            s = real(0.0)
            for c in range(d):
                s += (F[a, c] - R[a, c]) * F[b, c]
            tau[a, b] = scale * (real(2.0) * mu * s + (lam * (J - real(1.0)) * J if a == b else real(0.0)))


@pointwise(inline=True)
def fixed_corotated_stress(prm, F, J, Jp, tau, work):
    r"""Fixed-corotated stress (:func:`corotated_into`); ``prm`` = :math:`(\mu, \lambda, \rho)`."""
    real = tau.dtype.type
    corotated_into(F, real(prm[0]), real(prm[1]), real(1.0), tau, work)


@pointwise(inline=True)
def neo_hookean_stress(prm, F, J, Jp, tau, work):
    r"""``tau`` = :math:`\mu(FF^T - I) + \lambda \ln J\, I` (Bonet & Wood 2008 §6.4.3), :math:`J = \det F`;
    ``prm`` = :math:`(\mu, \lambda, \rho)`."""
    real = tau.dtype.type
    mu, lam = real(prm[0]), real(prm[1])
    d = F.shape[0]
    log_J = math.log(determinant(F))
    for a in range(d):
        for b in range(d):
            s = real(0.0)
            for c in range(d):
                s += F[a, c] * F[b, c]
            tau[a, b] = mu * (s - (real(1.0) if a == b else real(0.0))) + (lam * log_J if a == b else real(0.0))


@pointwise(inline=True)
def fluid_stress(prm, F, J, Jp, tau, work):
    r"""``tau`` = :math:`-pJ\,I`, :math:`p = K(J^{-\gamma} - 1)`: the Tait fluid of Becker & Teschner 2007 §4 and
    Tampubolon et al. 2017 §4.1 (:class:`mpmref.physics.materials.WeaklyCompressibleFluid`) at volume ratio ``J``;
    ``prm`` = :math:`(K, \gamma, \rho)`."""
    real = tau.dtype.type
    K, gamma = real(prm[0]), real(prm[1])
    power = real(1.0) / J if gamma == real(1.0) else math.pow(J, -gamma)
    s = -(K * (power - real(1.0))) * J
    for a in range(tau.shape[0]):
        for b in range(tau.shape[0]):
            tau[a, b] = s if a == b else real(0.0)


@pointwise(inline=True)
def snow_stress(prm, F, J, Jp, tau, work):
    r""":math:`\tau = e^{\xi(1 - J_P)}\,\tau_{corotated}(F_E)` (Stomakhin et al. 2013 §5); ``prm`` =
    :math:`(\mu, \lambda, \rho, \xi, \theta_c, \theta_s, J_P^{min}, J_P^{max})`."""
    real = tau.dtype.type
    corotated_into(F, real(prm[0]), real(prm[1]), math.exp(real(prm[3]) * (real(1.0) - Jp)), tau, work)


@pointwise(inline=True)
def hencky_strain(F, U, eps, Vt):
    r"""``U``, :math:`\epsilon = \ln\max(\sigma, \sigma_{floor})` into ``eps``, ``Vt`` (Klar et al. 2016 §4);
    returns :math:`\operatorname{tr}\epsilon`."""
    real = eps.dtype.type
    signed_svd(F, U, eps, Vt)
    trace = real(0.0)
    for a in range(F.shape[0]):
        eps[a] = math.log(max(eps[a], real(SIGMA_FLOOR)))
        trace += eps[a]
    return trace


@pointwise(inline=True)
def sand_stress(prm, F, J, Jp, tau, work):
    r"""``tau`` = :math:`U(2\mu\epsilon + \lambda\,\mathrm{tr}\,\epsilon\, I)U^T` (Klar et al. 2016 §4), unique where
    singular values repeat (equal :math:`\sigma_i`, equal principal stresses); ``prm`` =
    :math:`(\mu, \lambda, \rho, \alpha, c)`."""
    real = tau.dtype.type
    mu, lam = real(prm[0]), real(prm[1])
    U, Vt, Ut, eps = work[0], work[1], work[2], work[3, 0]
    trace = hencky_strain(F, U, eps, Vt)
    for a in range(F.shape[0]):
        eps[a] = real(2.0) * mu * eps[a] + lam * trace
        for b in range(F.shape[0]):
            Ut[a, b] = U[b, a]
    compose(U, eps, Ut, tau)


# ----------------------------------------------------------------------------------------------- return maps
@pointwise(inline=True)
def snow_return_map(prm, F, Jp, work):
    r"""Clamp :math:`\sigma_i` to :math:`[1-\theta_c, 1+\theta_s]` and move the excess into :math:`J_P` (Stomakhin et
    al. 2013 §4.1 step 7): ``F`` in place (unchanged, bit for bit, where already inside); returns
    :math:`\operatorname{clamp}(J_P \prod\sigma_i / \prod\hat\sigma_i, J_P^{min}, J_P^{max})`.

    :math:`U\hat\Sigma V^T` is unique even where singular values repeat (equal :math:`\sigma_i` clamp to equal
    :math:`\hat\sigma_i`), so the SVD's choice of :math:`U, V` there does not matter."""
    real = F.dtype.type
    U, Vt, sigma = work[0], work[1], work[3, 0]
    signed_svd(F, U, sigma, Vt)
    lo, hi = real(1.0) - real(prm[4]), real(1.0) + real(prm[5])
    inside = True
    before, after = real(1.0), real(1.0)
    for a in range(F.shape[0]):
        clamped = min(max(sigma[a], lo), hi)
        inside = inside and clamped == sigma[a]
        before *= sigma[a]
        after *= clamped
        sigma[a] = clamped
    if not inside:
        compose(U, sigma, Vt, F)
    return min(max(Jp * (before / after), real(prm[6])), real(prm[7]))


@pointwise(inline=True)
def sand_return_map(prm, F, Jp, work):
    r"""Drucker–Prager projection of the Hencky strain with the cohesion shift (Klar et al. 2016 Alg. 2;
    :meth:`mpmref.physics.plasticity.DruckerPragerSand.return_map`): ``F`` in place, returns the new
    :math:`J_P = J_P\,e^{\operatorname{tr}\epsilon - \operatorname{tr}\epsilon^{new}}`.

    :math:`U e^{\epsilon^{new}} V^T` is unique where singular values repeat: the projection maps equal strains to
    equal strains."""
    real = F.dtype.type
    mu, lam, alpha, cohesion = real(prm[0]), real(prm[1]), real(prm[3]), real(prm[4])
    d = F.shape[0]
    U, Vt, eps, eps_new = work[0], work[1], work[3, 0], work[3, 1]
    trace = hencky_strain(F, U, eps, Vt)
    norm2 = real(0.0)
    for a in range(d):
        norm2 += (eps[a] - trace / real(d)) * (eps[a] - trace / real(d))
    norm = math.sqrt(norm2)
    tr_shifted = trace - real(d) * cohesion
    dgamma = norm + (real(d) * lam + real(2.0) * mu) / (real(2.0) * mu) * tr_shifted * alpha
    if tr_shifted > real(0.0):
        for a in range(d):
            eps_new[a] = cohesion
    elif dgamma > real(0.0):
        for a in range(d):
            eps_new[a] = eps[a] - dgamma / norm * (eps[a] - trace / real(d)) if norm > real(0.0) else eps[a]
    else:
        return Jp
    trace_new = real(0.0)
    for a in range(d):
        trace_new += eps_new[a]
        eps_new[a] = math.exp(eps_new[a])
    compose(U, eps_new, Vt, F)
    return Jp * math.exp(trace - trace_new)


# ------------------------------------------------------------------------------------------------ wave speeds
@pointwise(inline=True)
def elastic_wave_speed(prm, F, J, Jp):
    r""":math:`c^2 = 4\mu J/(3\rho_0) + (2\mu/3 + \lambda)(1 - \ln J)/\rho_0`, at least the shear part,
    :math:`J = \max(\det F, 10^{-6})` (:func:`mpmref.physics.materials.elastic_wave_speeds`: the elastic solids, and
    sand at its elastic volume ratio); ``prm`` starts with :math:`(\mu, \lambda, \rho)`."""
    mu, lam, rho = prm[0], prm[1], prm[2]
    Jv = max(float(determinant(F)), J_FLOOR)
    shear = 4.0 * mu * Jv / (3.0 * rho)
    return math.sqrt(max(shear + (2.0 * mu / 3.0 + lam) * (1.0 - math.log(Jv)) / rho, shear))


@pointwise(inline=True)
def fluid_wave_speed(prm, F, J, Jp):
    r""":math:`c^2 = \gamma K / (\rho_0 J^{\gamma - 1})`, :math:`J \ge 10^{-6}`
    (:meth:`mpmref.physics.materials.WeaklyCompressibleFluid.wave_speeds`); ``prm`` = :math:`(K, \gamma, \rho)`."""
    K, gamma, rho = prm[0], prm[1], prm[2]
    return math.sqrt(gamma * K / (rho * math.pow(max(float(J), J_FLOOR), gamma - 1.0)))


@pointwise(inline=True)
def snow_wave_speed(prm, F, J, Jp):
    r""":math:`c^2 = (\lambda + 2\mu)\, e^{\xi(1 - J_P)} J / \rho_0`, :math:`J = \max(\det F_E\, J_P, 10^{-6})`
    (:meth:`mpmref.physics.plasticity.SnowPlasticity.wave_speeds`); ``prm`` as :func:`snow_stress`'s."""
    mu, lam, rho, hardening = prm[0], prm[1], prm[2], prm[3]
    Jv = max(float(determinant(F) * Jp), J_FLOOR)
    return math.sqrt((lam + 2.0 * mu) * math.exp(hardening * (1.0 - float(Jp))) * Jv / rho)


# ------------------------------------------------------------------------------- the declarations, read
def functions(law):
    """The pointwise functions a :class:`~mpmref.physics.materials.CompiledLaw` names: a namespace of ``stress``,
    ``return_map`` (``None`` for an elastic law) and ``wave_speed``."""
    module = importlib.import_module(law.module)
    return SimpleNamespace(stress=getattr(module, law.stress), wave_speed=getattr(module, law.wave_speed),
                           return_map=getattr(module, law.return_map) if law.return_map else None)


def law_digest(law):
    """A hash of the law's declaration and of the source file of its functions (a compiled kernel's closure
    constant: Numba's disk cache then tells the laws apart and sees their edits)."""
    source = inspect.getsourcefile(importlib.import_module(law.module))
    with open(source, "rb") as file:
        return hashlib.sha256(repr(law).encode() + file.read()).hexdigest()


def parameter_table(materials):
    """Every material's parameter row (the parameters its law declares, in order), float64, (k, widest row) with
    zeros after a shorter row."""
    rows = [[float(getattr(m, name)) for name in type(m).compiled.parameters] for m in materials]
    table = np.zeros((len(rows), max(len(r) for r in rows)))
    for i, row in enumerate(rows):
        table[i, :len(row)] = row
    return table


def laws_of(materials):
    """The distinct laws of ``materials`` in a fixed order (what a GPU kernel compiles in), and each material's index
    among them."""
    laws = tuple(sorted({type(m).compiled for m in materials}, key=repr))
    return laws, np.array([laws.index(type(m).compiled) for m in materials], dtype=np.int64)
