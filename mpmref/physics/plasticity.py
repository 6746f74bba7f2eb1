r"""Elastoplastic materials: snow (Stomakhin et al. 2013) and Drucker–Prager sand (Klar et al. 2016).

Both keep the *elastic* deformation gradient :math:`F = F_E` per particle (``tracks = "F"``) plus the
plastic volume ratio :math:`J_P` (``plastic = True``). The energy and the Kirchhoff stress
:math:`\tau = P F^T` are those of :math:`F_E`; after G2P the backend calls ``return_map(F, Jp)``, which
projects the trial :math:`F_E` back onto the admissible set, moves the excess into the plastic part and
updates :math:`J_P` so that :math:`J_P \det F_E` (the total volume ratio) is unchanged (up to the snow
model's clamp of :math:`J_P`):

.. math:: J_P^{new} = J_P \, \frac{\det F_E^{trial}}{\det F_E^{new}}.

Both projections act on the singular values of the SVD :math:`F = U\Sigma V^T`, taken with the sign
convention of :func:`~mpmref.physics.materials.polar_rotation`: where :math:`\det(UV^T) < 0` the last column
of :math:`U` and the last singular value change sign, so :math:`U, V` are proper rotations and an inverted
:math:`F` shows up as a negative last singular value.
"""

import math
from dataclasses import dataclass

import numpy as np

from .materials import CompiledLaw, FixedCorotated, LameParameters, determinant, elastic_wave_speeds, signed_svd
from .parameters import parameter

SIGMA_FLOOR = 1.0e-6
"""Smallest singular value the Hencky strain :math:`\\ln\\sigma` is taken of (sand): a compression of a
million to one, :math:`\\ln\\sigma \\ge -13.8`. Only an inverted or collapsed :math:`F` (signed
:math:`\\sigma \\le 0`) reaches it; the floor keeps the strain finite and strongly compressive there, so the
stress pushes the particle back instead of producing NaN."""


def _compose(U, sigma, Vt):
    r""":math:`U\,\mathrm{diag}(\sigma)\,V^T` for a batch."""
    return (U * sigma[:, None, :]) @ Vt


@dataclass(frozen=True)
class SnowPlasticity(LameParameters):
    r"""Snow: fixed-corotated elasticity with exponential hardening and a box-clamped elastic stretch.

    Stomakhin et al. 2013, "A material point method for snow simulation", §5 (energy density and
    hardening) and the deformation-gradient update (§4.1 step 7 with its plasticity):

    .. math::

        \Psi(F_E, J_P) = \mu(J_P) \sum_i (\sigma_i - 1)^2 + \frac{\lambda(J_P)}{2}(J_E - 1)^2,\qquad
        \mu(J_P) = \mu_0\, e^{\xi(1 - J_P)},\quad \lambda(J_P) = \lambda_0\, e^{\xi(1 - J_P)},

        \tau = e^{\xi(1 - J_P)}\left[2\mu_0 (F_E - R_E) F_E^T + \lambda_0 (J_E - 1) J_E\, I\right],

        \text{return map:}\quad \hat\sigma_i = \operatorname{clamp}(\sigma_i, 1 - \theta_c, 1 + \theta_s),\quad
        F_E^{new} = U \hat\Sigma V^T,\quad
        J_P^{new} = \operatorname{clamp}\!\Big(J_P \frac{\prod_i \sigma_i}{\prod_i \hat\sigma_i},\,
        J_P^{min}, J_P^{max}\Big).

    :math:`\sigma_i` are the signed singular values of the elastic gradient :math:`F_E`,
    :math:`R_E = UV^T` its polar rotation, :math:`J_E = \det F_E`, :math:`\mu_0, \lambda_0` the Lamé
    parameters of ``E``, ``nu``; :math:`\xi` = ``hardening``, :math:`\theta_c` = ``theta_c`` (critical
    compression), :math:`\theta_s` = ``theta_s`` (critical stretch). Defaults are the paper's reference
    snow (:math:`\theta_c = 2.5\times10^{-2}`, :math:`\theta_s = 7.5\times10^{-3}`, :math:`\xi = 10`).

    The clamp of :math:`J_P` is this toolkit's choice, not the paper's: ``Jp_min`` bounds the stiffening
    :math:`e^{\xi(1 - J_P)}` (:math:`e^4 \approx 54.6` at the defaults), so that the stiffest snow a run can
    reach, and with it the CFL time step of its particles (:meth:`wave_speeds`, the speed of each particle at its
    own :math:`J_P`), has a finite worst case; :meth:`wave_speed` is the speed at rest (:math:`J_P = 1`), where a
    scene starts; ``Jp_max`` keeps :math:`J_P` finite for snow that
    is torn apart (its softening :math:`e^{-19\xi}` already makes such snow stress-free). An inverted
    trial :math:`F_E` (signed :math:`\sigma_d < 0`) comes back un-inverted with
    :math:`\hat\sigma_d = 1-\theta_c`; its volume ratio is negative, so :math:`J_P` clamps to ``Jp_min``.

    Defaults and allowed ranges are declared on the fields (:func:`~mpmref.physics.parameters.parameter`);
    ``E``, ``nu`` and ``rho`` come from :class:`~mpmref.physics.materials.LameParameters`.
    """

    theta_c: float = parameter(default=2.5e-2, lo=0.0, hi=1.0, lo_open=True, hi_open=True)
    theta_s: float = parameter(default=7.5e-3, lo=0.0)
    hardening: float = parameter(default=10.0, lo=0.0, hi=100.0)
    Jp_min: float = parameter(default=0.6, lo=0.0, hi=1.0, lo_open=True)
    Jp_max: float = parameter(default=20.0, lo=1.0)
    tracks = "F"
    plastic = True
    #: the compiled backends' law (:class:`~mpmref.physics.materials.CompiledLaw`)
    compiled = CompiledLaw("snow_stress", "snow_wave_speed",
                           ("mu", "lam", "rho", "hardening", "theta_c", "theta_s", "Jp_min", "Jp_max"),
                           return_map="snow_return_map")

    def hardening_factor(self, Jp):
        r"""Stiffness multiplier :math:`e^{\xi(1 - J_P)}` of both Lamé parameters."""
        return np.exp(self.hardening * (1.0 - Jp))

    def _elastic(self):
        return FixedCorotated(E=self.E, nu=self.nu, rho=self.rho)

    def energy_density(self, F, Jp):
        return self.hardening_factor(Jp) * self._elastic().energy_density(F)

    def kirchhoff_stress(self, F, Jp):
        r"""Hardened fixed-corotated stress :math:`\tau = e^{\xi(1 - J_P)}\,\tau_{FC}(F_E)` (n, d, d).

        Docs: docs/materials.md#snow, docs/mpm_cycle.md#elastoplastic-materials
        """
        return self.hardening_factor(Jp)[:, None, None] * self._elastic().kirchhoff_stress(F)

    def return_map(self, F, Jp):
        """Clamp the elastic singular values; particles already inside keep ``F`` bit for bit.

        Docs: docs/materials.md#snow, docs/mpm_cycle.md#elastoplastic-materials
        """
        U, sigma, Vt = signed_svd(F)
        clamped = np.clip(sigma, 1.0 - self.theta_c, 1.0 + self.theta_s)
        inside = np.all(clamped == sigma, axis=1)
        F_new = np.where(inside[:, None, None], F, _compose(U, clamped, Vt))
        ratio = np.prod(sigma, axis=1) / np.prod(clamped, axis=1)
        return F_new, np.clip(Jp * ratio, self.Jp_min, self.Jp_max)

    def wave_speeds(self, F, Jp):
        r"""P-wave speed of each particle with its hardened Lamé parameters and current density.

        .. math:: c_p = \sqrt{(\lambda(J_P) + 2\mu(J_P))\, J / \rho_0}, \qquad J = \det F_E\, J_P

        (the snow rule of Fang et al. 2018's regional time stepping; :math:`\rho_0/J` is the current density).
        """
        J = np.maximum(determinant(F) * Jp, 1e-6)
        return np.sqrt((self.lam + 2.0 * self.mu) * self.hardening_factor(Jp) * J / self.rho)


@dataclass(frozen=True)
class DruckerPragerSand(LameParameters):
    r"""Sand: Hencky-strain St. Venant–Kirchhoff elasticity with a Drucker–Prager return map.

    Klar et al. 2016, "Drucker-Prager elastoplasticity for sand animation", §4 (energy) and §7.3 with
    Algorithm 2 (projection). With :math:`\epsilon = \ln\Sigma` the principal Hencky strains of the elastic
    gradient :math:`F_E = U\Sigma V^T`:

    .. math::

        \Psi(F_E) = \mu \operatorname{tr}(\epsilon^2) + \frac{\lambda}{2}(\operatorname{tr}\epsilon)^2,\qquad
        \tau = U\left(2\mu\,\epsilon + \lambda \operatorname{tr}(\epsilon)\, I\right)U^T.

    The return map works on the strain shifted by the cohesion :math:`c`,
    :math:`\epsilon' = \epsilon - c I` (deviator :math:`\hat\epsilon = \epsilon - \frac{\operatorname{tr}\epsilon}{d} I`
    unchanged), with

    .. math::

        \delta\gamma = \|\hat\epsilon\|_F + \frac{d\lambda + 2\mu}{2\mu}\operatorname{tr}(\epsilon')\,\alpha,
        \qquad \alpha = \sqrt{\tfrac{2}{3}}\,\frac{2\sin\phi}{3 - \sin\phi},

    and three cases: tension :math:`\operatorname{tr}\epsilon' > 0` goes to the cone tip,
    :math:`\epsilon^{new} = c I`; :math:`\delta\gamma \le 0` is inside the cone, unchanged; otherwise the
    deviator shrinks onto the cone, :math:`\epsilon^{new} = \epsilon - \delta\gamma\,\hat\epsilon/\|\hat\epsilon\|_F`
    (same trace). Then :math:`F_E^{new} = U e^{\epsilon^{new}} V^T` and
    :math:`J_P^{new} = J_P\, e^{\operatorname{tr}\epsilon - \operatorname{tr}\epsilon^{new}}`, which is
    :math:`J_P \det F_E / \det F_E^{new}` for every :math:`F_E` with singular values above
    :data:`SIGMA_FLOOR` (it stays positive below). The admissible set is, in stress terms,
    :math:`\|\hat\tau\|_F + \alpha\left(\operatorname{tr}\tau - (d\lambda + 2\mu)\,d\,c\right) \le 0`.

    ``cohesion`` :math:`c \ge 0` is not in Klar et al. (cohesionless sand, :math:`c = 0`): it moves the cone
    apex along the hydrostatic axis from :math:`\epsilon = 0` to :math:`\epsilon = cI`, i.e. it is the
    isotropic Hencky (log) stretch per direction that the sand sustains elastically, a tensile strength
    expressed as a strain; the corresponding mean Kirchhoff stress at the apex is :math:`(d\lambda + 2\mu)c`.
    :math:`\phi` is ``friction_angle`` in degrees, :math:`\mu, \lambda` the Lamé parameters, :math:`d` the
    dimension. ``Jp`` is only bookkeeping here; the stress does not depend on it.

    Defaults and allowed ranges are declared on the fields (:func:`~mpmref.physics.parameters.parameter`);
    ``E``, ``nu`` and ``rho`` come from :class:`~mpmref.physics.materials.LameParameters`.
    """

    friction_angle: float = parameter(default=30.0, lo=0.0, hi=90.0, hi_open=True)
    cohesion: float = parameter(default=0.0, lo=0.0, hi=1.0)
    tracks = "F"
    plastic = True
    #: the compiled backends' law (:class:`~mpmref.physics.materials.CompiledLaw`)
    compiled = CompiledLaw("sand_stress", "elastic_wave_speed", ("mu", "lam", "rho", "alpha", "cohesion"),
                           return_map="sand_return_map")

    @property
    def alpha(self):
        r"""Drucker–Prager friction coefficient :math:`\sqrt{2/3}\; 2\sin\phi / (3 - \sin\phi)`."""
        s = math.sin(math.radians(self.friction_angle))
        return math.sqrt(2.0 / 3.0) * 2.0 * s / (3.0 - s)

    @staticmethod
    def hencky_strain(F):
        r"""``U``, principal Hencky strains :math:`\ln\max(\sigma, \sigma_{floor})` (n, d), ``Vt``."""
        U, sigma, Vt = signed_svd(F)
        return U, np.log(np.maximum(sigma, SIGMA_FLOOR)), Vt

    def energy_density(self, F, Jp):
        _, eps, _ = self.hencky_strain(F)
        return self.mu * np.sum(eps**2, axis=1) + 0.5 * self.lam * np.sum(eps, axis=1) ** 2

    def kirchhoff_stress(self, F, Jp):
        r"""Hencky-strain St. Venant–Kirchhoff stress
        :math:`\tau = U(2\mu\epsilon + \lambda\,\mathrm{tr}\,\epsilon\,I)U^T`.

        Docs: docs/materials.md#sand, docs/mpm_cycle.md#elastoplastic-materials
        """
        U, eps, _ = self.hencky_strain(F)
        principal = 2.0 * self.mu * eps + self.lam * np.sum(eps, axis=1, keepdims=True)
        return _compose(U, principal, U.transpose(0, 2, 1))

    def return_map(self, F, Jp):
        """Klar et al. 2016 Algorithm 2 with the cohesion shift; unchanged particles keep ``F`` bit for bit.

        Docs: docs/materials.md#sand, docs/mpm_cycle.md#elastoplastic-materials
        """
        U, eps, Vt = self.hencky_strain(F)
        d = F.shape[1]
        tr_shifted = np.sum(eps, axis=1) - d * self.cohesion
        dev = eps - np.mean(eps, axis=1, keepdims=True)
        norm = np.linalg.norm(dev, axis=1)
        dgamma = norm + (d * self.lam + 2.0 * self.mu) / (2.0 * self.mu) * tr_shifted * self.alpha
        tension = tr_shifted > 0
        shrink = np.maximum(dgamma, 0.0) / np.where(norm > 0, norm, 1.0)
        eps_new = np.where(tension[:, None], self.cohesion, eps - shrink[:, None] * dev)
        changed = tension | (dgamma > 0)
        F_new = np.where(changed[:, None, None], _compose(U, np.exp(eps_new), Vt), F)
        return F_new, Jp * np.exp(np.sum(eps, axis=1) - np.sum(eps_new, axis=1))

    def wave_speeds(self, F, Jp):
        r"""Current wave speed of each particle: the elastic rule (:func:`~.materials.elastic_wave_speeds`)
        at the elastic volume ratio :math:`\det F_E`."""
        return elastic_wave_speeds(self.mu, self.lam, self.rho, determinant(F))
