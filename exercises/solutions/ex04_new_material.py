r"""Exercise 4: add a material by following the template of ``mpmref.physics.materials``.

Task. Add St. Venant–Kirchhoff elasticity, which mpmref does not have. With the Green strain
:math:`\mathcal E = \tfrac12(F^TF - I)`,

.. math::

    \Psi(F) = \mu \operatorname{tr}(\mathcal E^2) + \frac{\lambda}{2}(\operatorname{tr}\mathcal E)^2, \qquad
    P = \frac{\partial\Psi}{\partial F} = F\,(2\mu\,\mathcal E + \lambda \operatorname{tr}\mathcal E\, I), \qquad
    \tau = P F^T .

Follow the template of the elastic solids (``docs/materials.md``): subclass
``mpmref.physics.materials.ElasticSolid`` (parameters ``E``, ``nu``, ``rho``; Lamé parameters, wave speeds
and :math:`P = \tau F^{-T}` come with it) and provide ``energy_density(F)`` and ``kirchhoff_stress(F)``
for batches ``F`` of shape (n, d, d). Then make it pass the checks every mpmref material passes
(``tests/test_materials.py``).

Prediction: the checks below hold, for these reasons.

1. :math:`P = \partial\Psi/\partial F`, by central differences: the force of ``docs/mpm_cycle.md`` is the
   energy's gradient only if the stress is.
2. Zero stress at rest, :math:`\tau(I) = 0`.
3. Objectivity, :math:`\tau(RF) = R\,\tau(F)\,R^T` for a rotation :math:`R`: a rigid rotation of the
   deformed body rotates its stress and adds none.
4. The small-strain limit: every isotropic hyperelastic model with the same Lamé parameters agrees with
   linear elasticity to first order, so :math:`\tau_{SVK} - \tau_{NH} = O(\epsilon^2)` against mpmref's
   Neo-Hookean: halving :math:`\epsilon` quarters the difference.
5. Its wave speed at rest is the P-wave speed :math:`\sqrt{(\lambda + 2\mu)/\rho}` (inherited).
"""

from dataclasses import dataclass

import numpy as np

from mpmref.physics.materials import ElasticSolid, NeoHookean


@dataclass(frozen=True)
class StVenantKirchhoff(ElasticSolid):
    r"""St. Venant–Kirchhoff elasticity in the Green strain (the energy and stress above)."""

    def green_strain(self, F):
        return 0.5 * (F.transpose(0, 2, 1) @ F - np.eye(F.shape[1]))

    def energy_density(self, F):
        strain = self.green_strain(F)
        trace = np.trace(strain, axis1=1, axis2=2)
        return self.mu * np.einsum("nij,nij->n", strain, strain) + 0.5 * self.lam * trace ** 2

    def kirchhoff_stress(self, F):
        r""":math:`\tau = F(2\mu\mathcal E + \lambda\operatorname{tr}\mathcal E\,I)F^T`."""
        strain = self.green_strain(F)
        trace = np.trace(strain, axis1=1, axis2=2)
        second_piola = 2.0 * self.mu * strain + (self.lam * trace)[:, None, None] * np.eye(F.shape[1])
        return F @ second_piola @ F.transpose(0, 2, 1)


def numerical_piola(material, F, h=1e-6):
    """Central differences of the energy density with respect to each entry of ``F``."""
    P = np.zeros_like(F)
    for i in range(F.shape[1]):
        for j in range(F.shape[2]):
            step = np.zeros_like(F)
            step[:, i, j] = h
            P[:, i, j] = (material.energy_density(F + step) - material.energy_density(F - step)) / (2 * h)
    return P


def rotation(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def solve():
    rng = np.random.default_rng(4)
    svk = StVenantKirchhoff(E=1e3, nu=0.3, rho=1.0)
    F = np.eye(2) + 0.2 * rng.standard_normal((50, 2, 2))
    F = F[np.linalg.det(F) > 0.2]

    gradient_error = np.abs(svk.first_piola(F) - numerical_piola(svk, F)).max() / np.abs(svk.first_piola(F)).max()
    assert gradient_error < 1e-7, gradient_error                                   # 1. P = dPsi/dF
    assert np.abs(svk.kirchhoff_stress(np.eye(2)[None])).max() == 0.0               # 2. rest
    R = rotation(0.7)
    rotated = svk.kirchhoff_stress(R @ F)
    assert np.allclose(rotated, R @ svk.kirchhoff_stress(F) @ R.T, atol=1e-9)        # 3. objectivity

    neo = NeoHookean(E=1e3, nu=0.3, rho=1.0)
    A = rng.standard_normal((20, 2, 2))
    gaps = [np.abs(svk.kirchhoff_stress(np.eye(2) + eps * A) - neo.kirchhoff_stress(np.eye(2) + eps * A)).max()
            for eps in (1e-2, 5e-3)]
    order = np.log2(gaps[0] / gaps[1])
    assert abs(order - 2.0) < 0.1, order                                            # 4. small strain
    assert svk.wave_speed() == neo.wave_speed()                                      # 5. wave speed
    return {"relative_gradient_error": gradient_error, "small_strain_order": order}


if __name__ == "__main__":
    print(solve())
