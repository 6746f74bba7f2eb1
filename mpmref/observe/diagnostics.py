r"""Conserved and monitored quantities of a particle state.

Angular momentum includes the affine part carried by APIC/MLS particles (Jiang et al. 2015 §5.3):

.. math::

    L = \sum_p x_p \times m_p v_p + \sum_p m_p\, \epsilon : (C_p D_p)^T,

which for :math:`D_p = D I` is :math:`m_p D\,(C_{yx} - C_{xy})` about :math:`z` (and cyclically in 3D).
The affine kinetic energy :math:`\tfrac12 m_p \operatorname{tr}(C_p D_p C_p^T)` is reported separately.
"""

import numpy as np

from ..physics import polypic
from ..physics.kernels import compute_stencil
from ..physics.materials import material_groups, state_args


def cross(a, b):
    """2D: scalar cross product (n,); 3D: vector cross product (n, 3)."""
    if a.shape[1] == 2:
        return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return np.cross(a, b)


def affine_spin(C):
    r"""Axial vector of the skew part of :math:`C`: :math:`(C_{yx} - C_{xy})` in 2D, its 3D analogue.

    Docs: docs/transfers.md#angular-momentum
    """
    if C.shape[1] == 2:
        return C[:, 1, 0] - C[:, 0, 1]
    return np.stack([C[:, 2, 1] - C[:, 1, 2], C[:, 0, 2] - C[:, 2, 0], C[:, 1, 0] - C[:, 0, 1]], axis=1)


def angular_momentum(particles, inertia):
    """Total angular momentum about the origin (scalar in 2D, (3,) in 3D), affine part included.

    Docs: docs/transfers.md#angular-momentum
    """
    m = particles.mass.astype(np.float64)
    x, v = particles.x.astype(np.float64), particles.v.astype(np.float64)
    L = np.tensordot(m, cross(x, v), axes=1)
    if particles.C is not None:
        L = L + inertia * np.tensordot(m, affine_spin(particles.C.astype(np.float64)), axes=1)
    return L


def momentum_scale(particles):
    r""":math:`\sum_p m_p |v_p|` (float64): the largest :math:`|P|` the particles' momenta can add up to, so the
    scale against which a change of linear momentum is small or large. Unlike :math:`|P|` it is not zero when the
    momenta cancel (a spinning disk), only when every particle is at rest."""
    m = particles.mass.astype(np.float64)
    return float(np.sum(m * np.linalg.norm(particles.v.astype(np.float64), axis=1)))


def angular_momentum_scale(particles, inertia):
    r"""The largest :math:`|L|` that the parts of :func:`angular_momentum` can add up to, the scale of a change of
    angular momentum (float64). With the centre of mass :math:`x_c`, its velocity :math:`v_c = P/M` and
    :math:`L = x_c \times P + \sum_p m_p (x_p - x_c) \times (v_p - v_c) + D \sum_p m_p \operatorname{spin}(C_p)`,

    .. math::

        S_L = |x_c \times P| + \sum_p m_p\, |(x_p - x_c) \times (v_p - v_c)|
              + D \sum_p m_p\, |\operatorname{spin}(C_p)|,

    which is :math:`|L|` itself for a rigid rotation about the centre of mass, whatever the origin, and zero only
    when every particle is at rest (and, for the affine schemes, carries no spin)."""
    m = particles.mass.astype(np.float64)
    x, v = particles.x.astype(np.float64), particles.v.astype(np.float64)
    center, velocity = m @ x / m.sum(), m @ v / m.sum()
    total = float(np.sum(_magnitude(cross(center[None], m.sum() * velocity[None]))))
    total += float(np.sum(m * _magnitude(cross(x - center, v - velocity))))
    if particles.C is not None:
        total += inertia * float(np.sum(m * _magnitude(affine_spin(particles.C.astype(np.float64)))))
    return total


def _magnitude(a):
    """Per particle, the magnitude of a 2D scalar (n,) or a 3D vector (n, 3)."""
    return np.abs(a) if a.ndim == 1 else np.linalg.norm(a, axis=1)


def elastic_energies(particles, materials):
    r"""Each particle's stored energy :math:`V_p^0 \Psi(F_p)` (or :math:`V_p^0 \Psi(J_p)` for fluids), float64 (n,)."""
    energy = np.zeros(particles.n)
    for material, idx in material_groups(materials, particles):
        args = [a.astype(np.float64) for a in state_args(material, particles, idx)]
        energy[idx] = particles.vol0[idx] * material.energy_density(*args)
    return energy


def elastic_energy(particles, materials):
    r"""Total stored energy :math:`\sum_p V_p^0 \Psi(F_p)` (or :math:`\Psi(J_p)` for fluids): the sum of
    :func:`elastic_energies`."""
    return float(np.sum(elastic_energies(particles, materials)))


def polypic_mode_norms(particles, kernel, grid):
    r"""Squared norms :math:`\sum_i w_{ip} s_r(x_i)^2` of each particle's higher PolyPIC modes, (n, M)."""
    st = compute_stencil(kernel, particles.x.astype(np.float64), grid.origin, grid.dx)
    _, norm = polypic.axis_basis(st.w, st.fx, st.dx)
    return polypic.mode_norms(norm, polypic.higher_modes(grid.dim, kernel.support))


def kinetic_parts(particles, inertia, mode_norms=None):
    r"""The particles' kinetic energy in their velocity, affine part and PolyPIC modes, float64 (a 3-tuple):

    .. math::

        \tfrac12 \sum_p m_p |v_p|^2, \qquad \tfrac12 \sum_p m_p D \|C_p\|^2, \qquad
        \tfrac12 \sum_p m_p \sum_r |c_{pr}|^2 \sum_i w_{ip} s_r(x_i)^2

    (Jiang et al. 2015 §5.3 for the affine part with :math:`D_p = D I`; Fu et al. 2017 §5 for the modes, which
    are orthogonal on the stencil). ``inertia`` is :math:`D`, ``mode_norms`` the (n, M) norms
    :math:`\sum_i w_{ip} s_r^2` (:func:`polypic_mode_norms`); a part the particles do not carry is 0.
    """
    m = particles.mass.astype(np.float64)
    v = particles.v.astype(np.float64)
    kinetic = float(0.5 * np.sum(m * np.sum(v * v, axis=1)))
    affine = (float(0.5 * inertia * np.sum(m * np.sum(particles.C.astype(np.float64) ** 2, axis=(1, 2))))
              if particles.C is not None else 0.0)
    modes = float(np.sum(mode_energies(particles, mode_norms))) if particles.modes is not None else 0.0
    return kinetic, affine, modes


def mode_energies(particles, mode_norms):
    r"""Each particle's kinetic energy in its higher PolyPIC modes, float64 (n,):
    :math:`\tfrac12 m_p \sum_r |c_{pr}|^2 N_{pr}` with the (n, M) norms :math:`N_{pr} = \sum_i w_{ip} s_r(x_i)^2`
    (:func:`polypic_mode_norms`; the modes are orthogonal on the stencil, Fu et al. 2017 §5)."""
    m = particles.mass.astype(np.float64)
    return 0.5 * m * np.sum(mode_norms * np.sum(particles.modes.astype(np.float64) ** 2, axis=2), axis=1)


def gravitational_energy(particles, gravity):
    r"""Gravitational potential :math:`U = -\sum_p m_p\, g \cdot x_p`, float64 (``gravity`` the (d,) vector
    :math:`g`)."""
    return float(-np.sum(particles.mass.astype(np.float64)
                         * (particles.x.astype(np.float64) @ np.asarray(gravity, dtype=np.float64))))


def carried_keys(dim):
    """The names of the entries of a :func:`carried` record in ``dim`` dimensions."""
    return ("particles", "mass", *(f"momentum_{'xyz'[a]}" for a in range(dim)), "energy")


def carried(particles, materials, gravity, inertia, mode_norms=None):
    r"""What ``particles`` carry, the record a run keeps of the particles that enter and leave it (float64, (d + 3,),
    named by :func:`carried_keys`): their count, mass :math:`\sum_p m_p`, momentum :math:`\sum_p m_p v_p` and energy
    :math:`\sum_p e_p`, each particle's kinetic (velocity, affine and PolyPIC-mode parts), stored and gravitational
    energy: the :func:`diagnostics` of these particles alone (arguments as there)."""
    d = diagnostics(particles, materials, gravity, inertia, mode_norms)
    momentum = [d[f"momentum_{'xyz'[a]}"] for a in range(particles.dim)]
    return np.array([d["n_particles"], d["mass"], *momentum, d["total_energy"]], dtype=np.float64)


def diagnostics(particles, materials, gravity, inertia, mode_norms=None):
    r"""Mass, momenta, kinetic (particle, affine, higher modes), elastic, gravitational and total energy.

    The kinetic energy a particle carries in its velocity modes is
    :math:`\tfrac12 m_p (|v_p|^2 + \operatorname{tr}(C_p D_p C_p^T) + \sum_r |c_{pr}|^2 \sum_i w_{ip} s_r^2)`
    — the energy its polynomial velocity field puts on its stencil (modes are orthogonal).

    Parameters
    ----------
    particles : Particles;  materials : list of material objects (index = material id)
    gravity : (d,) array;   inertia : the scalar :math:`D_p` of the kernel (None if not constant)
    mode_norms : (n, M) array or None  PolyPIC higher-mode norms (:func:`polypic_mode_norms`)
    """
    m = particles.mass.astype(np.float64)
    v = particles.v.astype(np.float64)
    out = {"n_particles": particles.n, "mass": float(m.sum())}
    momentum = (m[:, None] * v).sum(axis=0)
    for a in range(particles.dim):
        out[f"momentum_{'xyz'[a]}"] = float(momentum[a])
    L = np.atleast_1d(angular_momentum(particles, inertia))
    if particles.dim == 2:
        out["angular_momentum"] = float(L[0])
    else:
        for a in range(3):
            out[f"angular_momentum_{'xyz'[a]}"] = float(L[a])
    out["kinetic"], out["kinetic_affine"], out["kinetic_modes"] = kinetic_parts(particles, inertia, mode_norms)
    out["elastic"] = elastic_energy(particles, materials)
    out["gravitational"] = gravitational_energy(particles, gravity)
    out["total_energy"] = (out["kinetic"] + out["kinetic_affine"] + out["kinetic_modes"] + out["elastic"]
                           + out["gravitational"])
    return out
