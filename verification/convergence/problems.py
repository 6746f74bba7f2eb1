r"""Analytic problems of the convergence case: the vibrating bar and an axis-aligned manufactured solution.

Each problem gives its scene on a grid of ``cells`` cells across its length, its exact displacement
:math:`u(X, t)` and velocity :math:`v(X, t)` at material points :math:`X` (the initial particle
positions), the velocity gradient used to start APIC's :math:`C_p`, the body force per unit mass that the
stepping loop adds on the grid (zero for the bar), its symmetry planes, its end time and the wavenumber
:math:`k` of its mode (the error bounds are written in :math:`k\Delta x`). Both live on grids with
``GHOSTS`` ghost cells beyond each symmetry plane, so that a particle's stencil never leaves the grid.
"""

import math
from dataclasses import dataclass

import numpy as np

from mpmref import SceneBuilder
from mpmref.physics.materials import lame_parameters

#: ghost cells beyond each symmetry plane (enough for the cubic B-spline: particles at x >= 0 reach x >= -Δx)
GHOSTS = 2


@dataclass(frozen=True)
class Plane:
    """A symmetry plane ``x[axis] = position`` sitting on grid node ``node`` along ``axis``.

    ``side`` is ``"low"`` when the material lies at larger coordinates (the plane bounds it from below),
    ``"high"`` when it lies at smaller ones.
    """

    axis: int
    node: int
    side: str


@dataclass(frozen=True)
class VibratingBar:
    r"""Axially vibrating bar, fixed at :math:`x = 0` and free at :math:`x = L`, in its first mode.

    .. math::

        u(X, t) = \frac{v_0}{\omega}\sin(\omega t)\sin(\beta X), \qquad
        v(X, t) = v_0 \cos(\omega t)\sin(\beta X), \qquad
        \beta = \frac{\pi}{2L}, \quad \omega = \beta\sqrt{E/\rho}

    Source: Sulsky, Chen & Schreyer 1994 and Bardenhagen 2002 (*J. Comput. Phys.* 180), the vibrating
    bar example; the solution is the first separable mode of :math:`\rho\,\ddot u = E\,u_{XX}` with
    :math:`u(0, t) = 0` and :math:`u_X(L, t) = 0`. :math:`L` is the length, :math:`E` Young's modulus,
    :math:`\rho` the density, :math:`v_0` the velocity amplitude.

    The engine is 2D/3D, so the bar is a strip one cell thick in :math:`y` with open transverse sides
    and a fixed-corotated material with :math:`\nu = 0`. For :math:`F = \mathrm{diag}(1 + u_X, 1)` that
    material gives :math:`P_{xx} = 2\mu u_X = E u_X` exactly (:math:`\lambda = 0`, :math:`R = I`) and no
    transverse stress, so the continuum problem is the linear wave equation above. The discrete problem
    stays exactly one-dimensional: every particle row carries the same state, so node masses, momenta and
    forces factor into an :math:`x` part times the same :math:`y` weight sum, and the node velocities do
    not depend on :math:`y`.
    """

    length: float = 25.0
    E: float = 100.0
    rho: float = 1.0
    v0: float = 0.1
    name = "bar"

    @property
    def wave_speed(self):
        return math.sqrt(self.E / self.rho)

    @property
    def wavenumber(self):
        """:math:`\\beta = \\pi / 2L`."""
        return math.pi / (2.0 * self.length)

    @property
    def omega(self):
        return self.wavenumber * self.wave_speed

    @property
    def max_speed(self):
        return self.v0

    def end_time(self):
        """A quarter period :math:`T/4 = \\pi / (2\\omega)`: the displacement is at its largest."""
        return math.pi / (2.0 * self.omega)

    def displacement_scale(self):
        return self.v0 / self.omega

    def velocity_scale(self):
        return self.v0

    def scene(self, cells, method, ppa):
        """A strip ``[0, L] x [0, Δx]`` of ``ppa`` × ``ppa`` particles per cell; ghost cells below x = 0, room beyond
        L."""
        dx = self.length / cells
        room = GHOSTS + math.ceil(2.0 * self.displacement_scale() / dx)  # the free end moves by v0/ω
        return (SceneBuilder(dim=2, name=f"bar_{cells}")
                .grid(size=[(cells + GHOSTS + room) * dx, 4 * dx], dx=dx, origin=[-GHOSTS * dx, -2 * dx])
                .method(**method).material("bar", "fixed_corotated", E=self.E, nu=0.0, rho=self.rho)
                .box("bar", lower=[0.0, 0.0], upper=[self.length, dx], ppc=ppa**2)
                .walls("open", width=0).time(dt=1.0).build())  # Δt is the case's, see convergence.time_step

    def planes(self, cells):
        """The fixed end: a symmetry plane at x = 0 (grid node ``GHOSTS``)."""
        return (Plane(axis=0, node=GHOSTS, side="low"),)

    def displacement(self, X, t):
        u = np.zeros_like(X)
        u[:, 0] = self.displacement_scale() * math.sin(self.omega * t) * np.sin(self.wavenumber * X[:, 0])
        return u

    def velocity(self, X, t):
        v = np.zeros_like(X)
        v[:, 0] = self.v0 * math.cos(self.omega * t) * np.sin(self.wavenumber * X[:, 0])
        return v

    def velocity_gradient(self, X, t):
        """:math:`\\partial v_x / \\partial X = v_0 \\beta \\cos(\\omega t)\\cos(\\beta X)` (the only entry)."""
        grad = np.zeros(X.shape + (X.shape[1],))
        grad[:, 0, 0] = self.v0 * self.wavenumber * math.cos(self.omega * t) * np.cos(self.wavenumber * X[:, 0])
        return grad

    def body_force(self, X, t):
        """None: the bar is free vibration."""
        return None


@dataclass(frozen=True)
class AxisAlignedMMS:
    r"""Axis-aligned manufactured solution on the unit square, compressible Neo-Hookean material.

    .. math::

        u_a(X, t) = A \sin(2\pi X_a)\sin(c\pi t), \qquad a = 1 \dots d, \qquad c = \sqrt{E/\rho_0}

    (Steffen, Wallstedt, Guilkey, Kirby & Berzins 2008, *CMES* 31, the 1D form, which Uintah's MMS code
    cites as their Eq. 47; applied per axis as in Wallstedt & Guilkey 2008, *J. Comput. Phys.* 227, and
    Uintah's MPM MMS tests).
    :math:`A` is the amplitude, :math:`E, \nu` the elastic constants, :math:`\rho_0` the reference density.

    The deformation gradient is diagonal, :math:`F_{aa} = 1 + 2\pi A\cos(2\pi X_a)\sin(c\pi t)`, and the
    engine's Neo-Hookean stress (Bonet & Wood 2008 §6.4.3) gives the diagonal first Piola stress

    .. math:: P_{aa} = \mu\left(F_{aa} - F_{aa}^{-1}\right) + \lambda \ln J\, F_{aa}^{-1}, \qquad J = \prod_b F_{bb}.

    Momentum balance in the reference configuration, :math:`\rho_0 \ddot u = \nabla_X\cdot P + \rho_0 b`,
    then fixes the body force per unit mass (the derivation is in ``docs/convergence.md``):

    .. math::

        b_a = \ddot u_a - \frac{1}{\rho_0}\frac{\partial P_{aa}}{\partial X_a}
            = -(c\pi)^2 u_a + \frac{4\pi^2 u_a}{\rho_0}
              \left[\mu\left(1 + F_{aa}^{-2}\right) + \lambda\,(1 - \ln J)\,F_{aa}^{-2}\right],

    using :math:`\partial F_{aa}/\partial X_a = -4\pi^2 u_a`. The solution is odd in the normal component
    about each face of the square and even in the tangential ones, so the faces are symmetry planes.
    """

    amplitude: float = 0.005
    E: float = 1.0e4
    nu: float = 0.3
    rho: float = 1.0
    dim: int = 2
    name = "mms"

    @property
    def c(self):
        """The time scale :math:`c = \\sqrt{E/\\rho_0}` of the manufactured solution."""
        return math.sqrt(self.E / self.rho)

    @property
    def wavenumber(self):
        return 2.0 * math.pi

    @property
    def max_speed(self):
        return self.amplitude * self.c * math.pi

    def end_time(self):
        """:math:`1 / (2c)`: :math:`\\sin(c\\pi t) = 1`, the displacement is at its largest."""
        return 1.0 / (2.0 * self.c)

    def displacement_scale(self):
        return self.amplitude

    def velocity_scale(self):
        return self.max_speed

    def scene(self, cells, method, ppa):
        dx = 1.0 / cells
        d = self.dim
        return (SceneBuilder(dim=d, name=f"mms_{cells}")
                .grid(size=(cells + 2 * GHOSTS) * dx, dx=dx, origin=[-GHOSTS * dx] * d)
                .method(**method).material("m", "neo_hookean", E=self.E, nu=self.nu, rho=self.rho)
                .box("m", lower=[0.0] * d, upper=[1.0] * d, ppc=ppa**d)
                .walls("open", width=0).time(dt=1.0).build())  # Δt is the case's, see convergence.time_step

    def planes(self, cells):
        """The four (six) faces of the unit square (cube)."""
        return tuple(Plane(axis=a, node=node, side=side) for a in range(self.dim)
                     for node, side in ((GHOSTS, "low"), (GHOSTS + cells, "high")))

    def displacement(self, X, t):
        return self.amplitude * np.sin(2.0 * np.pi * X) * math.sin(self.c * math.pi * t)

    def velocity(self, X, t):
        return self.amplitude * self.c * math.pi * np.sin(2.0 * np.pi * X) * math.cos(self.c * math.pi * t)

    def velocity_gradient(self, X, t):
        """Diagonal: :math:`\\partial v_a/\\partial X_a = 2\\pi^2 A c \\cos(2\\pi X_a)\\cos(c\\pi t)`."""
        diag = 2.0 * math.pi**2 * self.amplitude * self.c * np.cos(2.0 * np.pi * X) * math.cos(self.c * math.pi * t)
        return np.einsum("na,ab->nab", diag, np.eye(X.shape[1]))

    def body_force(self, X, t):
        """Body force per unit mass :math:`b(X, t)` (n, d) of the class docstring's equation."""
        mu, lam = lame_parameters(self.E, self.nu)
        u = self.displacement(X, t)
        F = 1.0 + 2.0 * math.pi * self.amplitude * np.cos(2.0 * np.pi * X) * math.sin(self.c * math.pi * t)
        log_J = np.sum(np.log(F), axis=1, keepdims=True)
        stiffness = mu * (1.0 + F**-2) + lam * (1.0 - log_J) * F**-2
        return -((self.c * math.pi) ** 2) * u + 4.0 * math.pi**2 * u * stiffness / self.rho


PROBLEMS = {"bar": VibratingBar, "mms": AxisAlignedMMS}
