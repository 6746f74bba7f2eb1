r"""Analytic level-set colliders on the grid (Stomakhin et al. 2013 §8; talk Eq. 25).

A collider is a signed distance function :math:`\phi(x)` (negative inside the obstacle) that moves
rigidly with constant velocity :math:`v_{co}`: at time :math:`t` it is :math:`\phi(x - v_{co} t)`. Every
grid node with mass and :math:`\phi(x_i) \le 0` has its velocity projected by
:func:`~mpmref.physics.boundary.project_velocity` with the outward normal :math:`n = \nabla\phi` and the
collider's velocity, type (sticky / slip / separate) and Coulomb friction.
"""

from dataclasses import dataclass

import numpy as np

from .boundary import project_velocity


def _unit(v):
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class Plane:
    r"""Half-space behind a plane through ``point`` with outward ``normal``: :math:`\phi = (x - p)\cdot n`."""

    point: np.ndarray
    normal: np.ndarray

    def sdf(self, x):
        return (x - self.point) @ _unit(self.normal)

    def gradient(self, x):
        return np.broadcast_to(_unit(self.normal), x.shape)


@dataclass(frozen=True)
class Ball:
    r"""Disk (2D) or sphere (3D): :math:`\phi = |x - c| - r`."""

    center: np.ndarray
    radius: float

    def sdf(self, x):
        return np.linalg.norm(x - self.center, axis=1) - self.radius

    def gradient(self, x):
        r = x - self.center
        norm = np.linalg.norm(r, axis=1, keepdims=True)
        return np.divide(r, norm, out=np.zeros_like(r), where=norm > 0)


@dataclass(frozen=True)
class Box:
    r"""Axis-aligned box ``lower .. upper``: :math:`\phi = |\max(q, 0)| + \min(\max_a q_a, 0)`,
    :math:`q = |x - c| - h` (c the centre, h the half-size; the exact box distance)."""

    lower: np.ndarray
    upper: np.ndarray

    def _q(self, x):
        c, h = 0.5 * (self.lower + self.upper), 0.5 * (self.upper - self.lower)
        return np.abs(x - c) - h, np.sign(x - c)

    def sdf(self, x):
        q, _ = self._q(x)
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)

    def gradient(self, x):
        q, sign = self._q(x)
        outside = np.maximum(q, 0.0)
        norm = np.linalg.norm(outside, axis=1, keepdims=True)
        inside = np.zeros_like(q)
        inside[np.arange(len(q)), np.argmax(q, axis=1)] = 1.0  # nearest face when inside
        g = np.where(norm > 0, np.divide(outside, norm, out=np.zeros_like(q), where=norm > 0), inside)
        return g * sign


@dataclass(frozen=True)
class Cylinder:
    r"""Infinite cylinder (3D) of ``radius`` around the axis through ``point`` along ``axis``:
    :math:`\phi = |(x - p) - ((x - p)\cdot a)a| - r`."""

    point: np.ndarray
    axis: np.ndarray
    radius: float

    def _radial(self, x):
        r = x - self.point
        a = _unit(self.axis)
        return r - (r @ a)[:, None] * a

    def sdf(self, x):
        return np.linalg.norm(self._radial(x), axis=1) - self.radius

    def gradient(self, x):
        r = self._radial(x)
        norm = np.linalg.norm(r, axis=1, keepdims=True)
        return np.divide(r, norm, out=np.zeros_like(r), where=norm > 0)


SHAPES = {"plane": Plane, "ball": Ball, "box": Box, "cylinder": Cylinder}


@dataclass(frozen=True)
class Collider:
    """A shape with its boundary type, friction and constant velocity."""

    shape: object
    type: str
    friction: float
    velocity: np.ndarray

    def apply(self, v, x, has_mass, time):
        """Project the velocities ``v`` (N, d) of massive nodes at ``x`` inside the collider at ``time`` (in place)."""
        moved = x - self.velocity * time
        phi = self.shape.sdf(moved)
        sel = has_mass & (phi <= 0.0)
        if sel.any():
            normal = self.shape.gradient(moved[sel])
            v[sel] = project_velocity(v[sel], normal, self.type, self.friction, self.velocity.astype(v.dtype))
        return v
