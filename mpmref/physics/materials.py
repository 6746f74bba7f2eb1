r"""Constitutive models: energy density, Kirchhoff stress and wave speed.

Each material works on a batch of deformation descriptors: the deformation gradient ``F`` of shape
``(n, d, d)`` for solids, or the volume ratio ``J`` of shape ``(n,)`` for the weakly compressible fluid
(``tracks`` says which). The Kirchhoff stress :math:`\tau = P F^T = J\sigma` is what the MLS-MPM force
needs (Hu et al. 2018 Eq. 18); ``first_piola`` gives :math:`P = \partial\Psi/\partial F` for checks.
"""

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .parameters import parameter

#: Poisson's ratio of a solid that stands in for a material of another type when none is given
#: (:meth:`LameParameters.with_wave_speed`)
STAND_IN_NU = 0.3


def lame_parameters(E, nu):
    r"""Lamé parameters from Young's modulus and Poisson's ratio.

    .. math:: \mu = \frac{E}{2(1+\nu)},\qquad \lambda = \frac{E\nu}{(1+\nu)(1-2\nu)}
    """
    return E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


def determinant(F):
    r""":math:`\det F` of each (d, d) matrix of ``F`` (n, d, d), d = 2 or 3, by its cofactor expansion
    (vectorised; LAPACK's batched ``det`` factorises every small matrix, an order of magnitude slower)."""
    if F.shape[1] == 2:
        return F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]
    return (F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
            - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
            + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]))


def signed_svd(F):
    r"""Batched SVD :math:`F = U\,\mathrm{diag}(\sigma)\,V^T` with :math:`U, V` proper rotations.

    Where :math:`\det(UV^T) < 0` the last column of :math:`U` and the last (smallest) singular value
    are negated (Irving et al. 2004 §4), so an inverted :math:`F` shows as a negative last singular value.
    Returns ``U`` (n, d, d), ``sigma`` (n, d), ``Vt`` (n, d, d).

    The reference keeps LAPACK (``np.linalg.svd``) on purpose: the Numba backend uses the fast closed-form
    (2D) and Jacobi (3D) factorisation of :mod:`mpmref.physics.svd`, and the conformance harness can only
    check that against an *independent* implementation. Both are backward stable, so they agree to
    round-off on every stress and return map (see :mod:`mpmref.physics.svd`).
    """
    U, sigma, Vt = np.linalg.svd(F)
    flip = np.linalg.det(U) * np.linalg.det(Vt) < 0
    U[flip, :, -1] *= -1.0
    sigma[flip, -1] *= -1.0
    return U, sigma, Vt


def polar_rotation(F):
    r"""Rotation :math:`R = UV^T` of the polar decomposition :math:`F = RS` and the signed singular values.

    Uses :func:`signed_svd`, so :math:`R` is a proper rotation (Stomakhin et al. 2012 §4).
    """
    U, sigma, Vt = signed_svd(F)
    return U @ Vt, sigma


@dataclass(frozen=True)
class CompiledLaw:
    """How the compiled backends (Numba, GPU) compute a material, declared next to its reference class (its class
    attribute ``compiled``): the names of its law's pointwise functions in ``module`` (the three signatures are those
    of :mod:`mpmref.backends.pointwise.laws`, where the toolkit's own are), and the parameters they read, in order:
    the material's *parameter row*. ``return_map`` is ``None`` for an elastic material (``plastic`` false)."""

    stress: str
    wave_speed: str
    parameters: tuple
    return_map: str = None
    module: str = "mpmref.backends.pointwise.laws"


@dataclass(frozen=True)
class Material:
    """What every material declares: its rest density ``rho`` (:math:`\\rho`, so that :math:`m_p = \\rho V_p^0`).

    Parameters are declared with :func:`~mpmref.physics.parameters.parameter` (default and allowed range);
    the scene validator reads them from there.
    """

    rho: float = parameter(default=1000.0, lo=0.0, lo_open=True)
    #: whether the stored energy is a function of the deformation alone, so that a step without transfer loss
    #: conserves energy (False: plastic flow dissipates it)
    hyperelastic = False
    #: whether the material has a return map and carries the plastic volume ratio ``Jp``
    plastic = False


@dataclass(frozen=True)
class LameParameters(Material):
    """Materials with Young's modulus ``E`` and Poisson's ratio ``nu``: the Lamé parameters ``mu`` and ``lam``."""

    E: float = parameter(lo=0.0, lo_open=True)
    nu: float = parameter(default=0.3, lo=0.0, hi=0.5, hi_open=True)

    @property
    def mu(self):
        return float(lame_parameters(self.E, self.nu)[0])

    @property
    def lam(self):
        return float(lame_parameters(self.E, self.nu)[1])

    def wave_speed(self):
        r"""Dilatational (P-)wave speed at rest (:math:`F = I`, :math:`J_P = 1`),
        :math:`c = \sqrt{(\lambda + 2\mu)/\rho}`.

        The speed a scene starts from, for set-up (a Mach number, a first Δt); each step's CFL rule uses every
        particle's current speed (``wave_speeds``).
        """
        return float(np.sqrt((self.lam + 2.0 * self.mu) / self.rho))

    @classmethod
    def with_wave_speed(cls, rho, c, given):
        r"""The parameters (a dict) of a material of this class of density :math:`\rho` and rest P-wave speed
        :math:`c`, keeping the values ``given`` (parameters a code fixes, or carried over from another material).

        .. math:: E = \rho c^2\,\frac{(1+\nu)(1-2\nu)}{1-\nu}
                  \qquad\text{so that}\qquad \lambda + 2\mu = \rho c^2,

        with :math:`\nu` the given one or :data:`STAND_IN_NU`; a given :math:`E` is kept (the speed is then its own).
        """
        nu = given.get("nu", STAND_IN_NU)
        return {"rho": rho, "E": rho * c**2 * (1 + nu) * (1 - 2 * nu) / (1 - nu), "nu": nu, **given}


@dataclass(frozen=True)
class ElasticSolid(LameParameters):
    """Shared parameters of the hyperelastic solids: Young's modulus ``E``, Poisson ratio ``nu``, density ``rho``."""

    tracks = "F"
    hyperelastic = True

    def wave_speeds(self, F):
        r"""P-wave speed of each particle in its current state (the CFL rule's :math:`c_p`); see
        :func:`elastic_wave_speeds`."""
        return elastic_wave_speeds(self.mu, self.lam, self.rho, determinant(F))

    def first_piola(self, F):
        r"""First Piola–Kirchhoff stress :math:`P = \tau F^{-T}`."""
        return self.kirchhoff_stress(F) @ np.linalg.inv(F).transpose(0, 2, 1)


@dataclass(frozen=True)
class FixedCorotated(ElasticSolid):
    r"""Fixed-corotated elasticity (Stomakhin et al. 2012 §4).

    .. math::

        \Psi(F) = \mu \sum_i (\sigma_i - 1)^2 + \frac{\lambda}{2}(J - 1)^2, \qquad
        \tau = P F^T = 2\mu (F - R) F^T + \lambda (J - 1) J\, I

    :math:`\sigma_i` are the singular values of :math:`F`, :math:`R` its polar rotation,
    :math:`J = \det F`, :math:`\mu, \lambda` the Lamé parameters.
    """

    #: the compiled backends' law (:class:`CompiledLaw`)
    compiled = CompiledLaw("fixed_corotated_stress", "elastic_wave_speed", ("mu", "lam", "rho"))

    def energy_density(self, F):
        _, sigma = polar_rotation(F)
        J = np.prod(sigma, axis=1)
        return self.mu * np.sum((sigma - 1.0) ** 2, axis=1) + 0.5 * self.lam * (J - 1.0) ** 2

    def kirchhoff_stress(self, F):
        r"""Kirchhoff stress :math:`\tau = 2\mu(F - R)F^T + \lambda(J - 1)J\,I` of each ``F`` (n, d, d).

        Docs: docs/materials.md#fixed-corotated, docs/mpm_cycle.md#materials
        """
        R, _ = polar_rotation(F)
        J = np.linalg.det(F)
        eye = np.eye(F.shape[1], dtype=F.dtype)
        return 2.0 * self.mu * (F - R) @ F.transpose(0, 2, 1) + (self.lam * (J - 1.0) * J)[:, None, None] * eye


def log_volume_ratio(J):
    r""":math:`\ln J` of each volume ratio ``J``: NaN for an inverted particle (:math:`J < 0`) and :math:`-\infty`
    for a collapsed one (:math:`J = 0`), whose energy and stress are not defined, without NumPy's
    ``RuntimeWarning`` (the Numba backend's ``log`` gives the same): the run's own check then stops it where the
    non-finite value reaches the particles, with :class:`~mpmref.errors.NonFiniteError` naming the step and
    particle."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.log(J)


@dataclass(frozen=True)
class NeoHookean(ElasticSolid):
    r"""Compressible Neo-Hookean elasticity (Bonet & Wood 2008 §6.4.3; Sifakis & Barbič 2012 §3.4).

    .. math::

        \Psi(F) = \frac{\mu}{2}\left(\operatorname{tr}(F^TF) - d\right) - \mu \ln J + \frac{\lambda}{2}(\ln J)^2,
        \qquad \tau = \mu (F F^T - I) + \lambda \ln J\, I

    :math:`d` is the dimension, :math:`J = \det F > 0`.
    """

    #: the compiled backends' law (:class:`CompiledLaw`)
    compiled = CompiledLaw("neo_hookean_stress", "elastic_wave_speed", ("mu", "lam", "rho"))

    def energy_density(self, F):
        logJ = log_volume_ratio(np.linalg.det(F))
        d = F.shape[1]
        return 0.5 * self.mu * (np.einsum("nij,nij->n", F, F) - d) - self.mu * logJ + 0.5 * self.lam * logJ**2

    def kirchhoff_stress(self, F):
        r"""Kirchhoff stress :math:`\tau = \mu(FF^T - I) + \lambda \ln J\,I` of each ``F`` (n, d, d).

        Docs: docs/materials.md#neo-hookean, docs/mpm_cycle.md#materials
        """
        logJ = log_volume_ratio(np.linalg.det(F))
        d = F.shape[1]
        tau = self.mu * (F @ F.transpose(0, 2, 1) - np.eye(d, dtype=F.dtype))
        tau[:, range(d), range(d)] += (self.lam * logJ)[:, None]     # on the diagonal only, as the Numba kernel
        return tau


@dataclass(frozen=True)
class WeaklyCompressibleFluid(Material):
    r"""Weakly compressible fluid with a Tait-type equation of state, tracking only :math:`J`.

    .. math::

        p = K\,(J^{-\gamma} - 1), \qquad
        \Psi(J) = K\left(\frac{J^{1-\gamma}}{\gamma - 1} + J - \frac{\gamma}{\gamma-1}\right)
        \;(\gamma \ne 1),\quad \Psi(J) = K\,(J - 1 - \ln J)\;(\gamma = 1),

    so that :math:`p = -\mathrm d\Psi/\mathrm dJ` and the Kirchhoff stress is
    :math:`\tau = -pJ\,I = K(J - J^{1-\gamma})\,I`. Source: Tait equation as used for weakly compressible
    fluids in Becker & Teschner 2007 §4 and Tampubolon et al. 2017 §4.1; with :math:`\gamma=1`,
    :math:`K=400`, :math:`\rho=1` this is the fluid of Taichi's ``mpm88`` example (Hu et al. 2019, the
    "88-line" program). :math:`K` is the bulk stiffness, :math:`\gamma` the exponent, :math:`\rho` density.
    """

    K: float = parameter(lo=0.0, lo_open=True)
    gamma: float = parameter(default=7.0, lo=1.0, hi=20.0)
    tracks = "J"
    hyperelastic = True
    #: the compiled backends' law (:class:`CompiledLaw`)
    compiled = CompiledLaw("fluid_stress", "fluid_wave_speed", ("K", "gamma", "rho"))

    @classmethod
    def with_wave_speed(cls, rho, c, given):
        r"""The parameters (a dict) of a fluid of density :math:`\rho` and sound speed :math:`c` at rest, keeping the
        values ``given``: :math:`K = \rho c^2/\gamma` (:meth:`wave_speed`), with the given :math:`\gamma` or its
        default; a given :math:`K` is kept."""
        gamma = given.get("gamma", cls.gamma)
        return {"rho": rho, "K": rho * c**2 / gamma, "gamma": gamma, **given}

    def pressure(self, J):
        r"""Tait pressure :math:`p = K(J^{-\gamma} - 1)` of each volume ratio ``J`` (n,).

        Docs: docs/mpm_cycle.md#materials
        """
        return self.K * (J ** (-self.gamma) - 1.0)

    def energy_density(self, J):
        if self.gamma == 1.0:
            return self.K * (J - 1.0 - log_volume_ratio(J))
        g = self.gamma
        return self.K * (J ** (1.0 - g) / (g - 1.0) + J - g / (g - 1.0))

    def kirchhoff_stress_from_J(self, J, dim):
        r"""Kirchhoff stress :math:`\tau = -pJ\,I` (n, ``dim``, ``dim``) of each volume ratio ``J`` (n,).

        Docs: docs/materials.md#weakly-compressible-fluid-tait, docs/mpm_cycle.md#materials
        """
        eye = np.eye(dim, dtype=J.dtype)
        return (-self.pressure(J) * J)[:, None, None] * eye

    def wave_speed(self):
        r"""Sound speed at rest, :math:`c = \sqrt{\gamma K / \rho}` (bulk modulus
        :math:`-J\,dp/dJ = \gamma K` at J = 1)."""
        return float(np.sqrt(self.gamma * self.K / self.rho))

    def wave_speeds(self, J):
        r"""Sound speed of each particle at its volume ratio :math:`J`.

        .. math:: c_p^2 = \frac{B(J_p)}{\rho_0 / J_p} = \frac{\gamma K}{\rho_0\, J_p^{\gamma - 1}}

        :math:`B = -J\,\mathrm dp/\mathrm dJ = \gamma K J^{-\gamma}` is the bulk modulus of the Tait law
        above and :math:`\rho_0/J` the current density (the water rule of Fang et al. 2018's regional
        time stepping). Compression (:math:`J < 1`, :math:`\gamma > 1`) makes sound faster.
        """
        return np.sqrt(self.gamma * self.K / (self.rho * np.maximum(J, 1e-6) ** (self.gamma - 1.0)))


def elastic_wave_speeds(mu, lam, rho, J):
    r"""Dilatational wave speed of elastic particles at volume ratio :math:`J` (Lamé parameters may be arrays).

    .. math:: c_p^2 = \frac{4\mu}{3\rho_p} + \frac{K\,(1 - \ln J_p)}{\rho_0}, \qquad
              K = \tfrac23\mu + \lambda, \qquad \rho_p = \rho_0 / J_p

    the rule of Fang et al. 2018's regional time stepping for elastic solids and sand: the shear part at
    the current density and the bulk part stiffened logarithmically under compression. At rest
    (:math:`J = 1`) it is the P-wave speed :math:`\sqrt{(\lambda + 2\mu)/\rho_0}`. :math:`\mu, \lambda`:
    Lamé parameters; :math:`\rho_0`: rest density. Negative :math:`c^2` (only for :math:`J > e^{1+4\mu/3K}`,
    torn material) is clipped to the shear part; :math:`J < 10^{-6}` (including inverted particles) is
    taken as :math:`10^{-6}`, the stiffest state the rule can express.
    """
    J = np.maximum(J, 1e-6)
    shear = 4.0 * mu * J / (3.0 * rho)
    return np.sqrt(np.maximum(shear + (2.0 * mu / 3.0 + lam) * (1.0 - np.log(J)) / rho, shear))


def material_groups(materials, particles):
    """``(material, idx)`` for each material of the list that has particles (``idx``: int64 indices, in order).

    The one per-material dispatch of the toolkit: backends (through their kernel tables), diagnostics, the
    CFL rule and outputs all group particles by material here.
    """
    if len(materials) == 1:
        return [(materials[0], np.arange(particles.n, dtype=np.int64))]
    groups = []
    for mat_id, material in enumerate(materials):
        idx = np.flatnonzero(particles.material == mat_id)
        if idx.size:
            groups.append((material, idx))
    return groups


def evolved_fields(material):
    """The deformation fields a material's particles carry and evolve: ``("J",)`` for the fluid, ``("F",)`` for the
    elastic solids, ``("F", "Jp")`` for the plastic ones. The other fields a scene allocates (a fluid's ``F`` in a
    scene with solids, a solid's ``J``) mean nothing for its particles; the conformance harness compares only these
    (besides ``x``, ``v`` and the scheme's ``C`` or modes, which every particle evolves)."""
    if material.tracks == "J":
        return ("J",)
    return ("F", "Jp") if getattr(material, "plastic", False) else ("F",)


def state_args(material, particles, sel):
    """The per-particle state a material's functions take (its :func:`evolved_fields`): ``(J,)``, ``(F,)`` or
    ``(F, Jp)`` for plastic ones."""
    return tuple(getattr(particles, name)[sel] for name in evolved_fields(material))


def wave_speed_of(material, particles, sel):
    """Current wave speed (m,) of the selected particles of ``material`` (the CFL rule's :math:`c_p`)."""
    return material.wave_speeds(*state_args(material, particles, sel))


def kirchhoff_stress_of(material, particles, sel):
    r"""Kirchhoff stress :math:`\tau` (m, d, d) of the selected particles of ``material``."""
    if material.tracks == "J":
        return material.kirchhoff_stress_from_J(particles.J[sel], particles.dim)
    return material.kirchhoff_stress(*state_args(material, particles, sel))


def wave_speeds_of(materials, particles, idx):
    r"""Current wave speed :math:`c_p` of the particles ``idx`` of ``particles`` (float64), reading only their rows.

    The elastic solids that share :meth:`~mpmref.physics.materials.ElasticSolid.wave_speeds` (fixed-corotated
    and Neo-Hookean, whatever their parameters) are done in one pass, with per-particle Lamé parameters and
    density; each other material on its own.
    """
    c = np.zeros(idx.size)
    material_of = particles.material[idx]
    shared, lame = _shared_elastic(tuple(materials))
    if shared.any():
        where = np.flatnonzero(shared[material_of]) if not shared.all() else np.arange(idx.size)
        mu, lam, rho = lame[material_of[where]].T
        c[where] = elastic_wave_speeds(mu, lam, rho, determinant(particles.F[idx[where]]))
    for mat_id in np.flatnonzero(~shared):
        where = np.flatnonzero(material_of == mat_id)
        if where.size:
            c[where] = wave_speed_of(materials[mat_id], particles, idx[where])
    return c


@lru_cache(maxsize=32)
def _shared_elastic(materials):
    """Which materials share :meth:`~mpmref.physics.materials.ElasticSolid.wave_speeds`, and every material's
    ``(mu, lam, rho)`` (placeholders for the others)."""
    shared = np.array([type(m).wave_speeds is ElasticSolid.wave_speeds for m in materials])
    lame = np.array([[m.mu, m.lam, m.rho] if s else [0.0, 0.0, 1.0] for m, s in zip(materials, shared)])
    return shared, lame
