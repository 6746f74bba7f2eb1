"""Turn a scene's bodies into particles: sample, assign mass/volume, initial velocity and state."""

from pathlib import Path

import numpy as np

from ..errors import SceneError
from ..physics.interface import skew_from_axial
from ..physics.polypic import higher_modes
from ..state import Particles


def _lattice(lower, upper, spacing, rng=None):
    """Cell-centred lattice points of ``spacing`` filling the box; jittered within their cells if ``rng``."""
    axes = [np.arange(lo + 0.5 * h, hi, h) for lo, hi, h in zip(lower, upper, spacing)]
    mesh = np.meshgrid(*axes, indexing="ij")
    pts = np.stack([m.ravel() for m in mesh], axis=1)
    if rng is not None:
        pts = pts + (rng.random(pts.shape) - 0.5) * spacing
    return pts


def _candidates(lower, upper, params, dx, dim):
    """Points filling a bounding box at the body's density, and the volume each one stands for."""
    ppc = params["ppc"]
    rng = np.random.default_rng(params["seed"])
    if params["sampling"] == "random":
        box_volume = float(np.prod(upper - lower))
        count = params["count"] or max(1, int(round(ppc * box_volume / dx**dim)))
        pts = lower + rng.random((count, dim)) * (upper - lower)
        return pts, box_volume / count
    per_axis = round(ppc ** (1.0 / dim)) if params["sampling"] == "regular" else None
    if per_axis is not None:
        spacing = np.full(dim, dx / per_axis)
    else:  # jittered: ppc sub-cells per cell, as close to cubic as the count allows
        spacing = np.full(dim, dx / ppc ** (1.0 / dim))
    # align the lattice with the grid so that regular sampling puts ppc points in every full cell
    lo = np.floor(lower / spacing) * spacing
    pts = _lattice(lo, upper, spacing, rng if params["sampling"] == "jittered" else None)
    return pts, float(np.prod(spacing))


def _inside_simplices(pts, vertices, simplices):
    """Boolean mask of points inside any of the given triangles (2D) or tetrahedra (3D)."""
    inside = np.zeros(len(pts), dtype=bool)
    for simplex in simplices:
        corners = vertices[simplex]
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        near = np.nonzero(np.all((pts >= lo) & (pts <= hi), axis=1))[0]
        if near.size == 0:
            continue
        T = (corners[1:] - corners[0]).T
        lam = np.linalg.solve(T, (pts[near] - corners[0]).T).T
        hit = np.all(lam >= 0, axis=1) & (lam.sum(axis=1) <= 1)
        inside[near[hit]] = True
    return inside


def _read_mesh_points(body, dim, dx, base_dir):
    """Particles of a ``mesh`` body: fill its triangles/tetrahedra, or take its points as a point cloud."""
    import meshio

    path = Path(body.params["file"])
    path = path if path.is_absolute() else Path(base_dir) / path
    try:
        mesh = meshio.read(path)
    except Exception as exc:  # meshio raises several types for unreadable files
        raise SceneError(f"bodies[{body.index}].file", str(path), f"a mesh readable by meshio ({exc})") from None
    vertices = np.asarray(mesh.points, dtype=np.float64)[:, :dim]
    cell_type = "triangle" if dim == 2 else "tetra"
    simplices = [c.data for c in mesh.cells if c.type == cell_type]
    if not simplices:  # a point cloud: each point is one particle of the body's density
        volume = body.params["particle_volume"] or dx**dim / body.params["ppc"]
        return vertices, volume
    simplices = np.concatenate(simplices)
    pts, volume = _candidates(vertices.min(axis=0), vertices.max(axis=0), body.params, dx, dim)
    return pts[_inside_simplices(pts, vertices, simplices)], volume


def sample_body(body, dim, dx, base_dir="."):
    """Positions and per-particle volume of one body, before any validation against the grid."""
    p = body.params
    if body.shape == "box":
        pts, volume = _candidates(p["lower"], p["upper"], p, dx, dim)
        keep = np.all((pts >= p["lower"]) & (pts < p["upper"]), axis=1)
        pts = pts[keep]
    elif body.shape in ("disk", "sphere"):
        c, r = p["center"], p["radius"]
        pts, volume = _candidates(c - r, c + r, p, dx, dim)
        pts = pts[np.sum((pts - c) ** 2, axis=1) < r * r]
    elif body.shape == "points":
        pts, volume = p["positions"], dx**dim / p["ppc"]
    else:
        pts, volume = _read_mesh_points(body, dim, dx, base_dir)
    if p["particle_volume"] is not None:
        volume = p["particle_volume"]
    if len(pts) == 0:
        raise SceneError(f"bodies[{body.index}]", body.shape, "a body that contains at least one particle")
    return pts, volume


def initial_velocity(pts, p):
    r"""A body's initial velocity at ``pts`` and its (constant) gradient: the affine field

    .. math::

        v(x) = v_0 + \omega \times (x - c) + G\,(x - c), \qquad \nabla v = W(\omega) + G,

    with :math:`v_0` the body's ``velocity``, :math:`\omega` its ``angular_velocity`` (:math:`W(\omega)\,r = \omega
    \times r`, the skew matrix whose axial vector in the sense of :func:`mpmref.observe.diagnostics.affine_spin` is
    :math:`2\omega`), :math:`G` its ``velocity_gradient`` (d × d; :math:`G = sI` is a uniform expansion at rate
    :math:`s`) and :math:`c` its ``rotation_center`` (default: the centroid of ``pts``).

    The affine schemes start from :math:`C_p = \nabla v` (:func:`sample_particles`), the one value consistent with
    this field: APIC's G2P sets :math:`C_p = B_p D_p^{-1}`, which for grid velocities sampled from an affine field
    is its gradient exactly (Jiang et al. 2015, *The affine particle-in-cell method*, §5; with this start a P2G of
    :math:`m_p(v_p + C_p(x_i - x_p))` gives every node :math:`v(x_i)` exactly, so the first transfer changes
    nothing); MLS-MPM takes the same :math:`C_p` as its velocity gradient (Hu et al. 2018, §4); PolyPIC's linear
    modes are :math:`C_p` (stored as ``C``, :mod:`mpmref.physics.polypic`) and its higher modes are zero for a
    linear field.
    """
    center = p["rotation_center"] if p["rotation_center"] is not None else pts.mean(axis=0)
    omega = np.asarray(p["angular_velocity"], dtype=np.float64)
    grad = skew_from_axial(2.0 * omega[None])[0] + p["velocity_gradient"]
    return p["velocity"] + (pts - center) @ grad.T, grad


def sample_particles(scene):
    """Sample every body of ``scene`` and return a :class:`~mpmref.state.Particles` of the scene's dtype.

    ``C`` is allocated only for affine schemes and starts at the gradient of each body's affine initial velocity
    field (:func:`initial_velocity`: translation, spin and ``velocity_gradient``); PolyPIC's higher ``modes`` start at
    zero; ``F`` starts at the
    identity, ``J`` and ``Jp`` at one. Raises
    :class:`~mpmref.errors.SceneError` if a body has particles outside the grid's valid region.
    """
    dim, dx = scene.dim, scene.grid.dx
    lo, hi = scene.valid_region()
    names = list(scene.materials)
    parts = {"x": [], "v": [], "mass": [], "vol0": [], "material": [], "C": []}
    for body in scene.bodies:
        pts, volume = sample_body(body, dim, dx, scene.base_dir)
        outside = np.any((pts < lo) | (pts >= hi), axis=1)
        if outside.any():
            first = pts[np.argmax(outside)]
            raise SceneError(f"bodies[{body.index}]", f"{int(outside.sum())} particle(s), first at {first.tolist()}",
                             f"particles inside the grid's valid region {lo.tolist()} .. {hi.tolist()} "
                             f"(the {scene.method.kernel} kernel's stencil must fit on the grid)")
        material = scene.materials[body.material]
        v, grad = initial_velocity(pts, body.params)
        n = len(pts)
        parts["x"].append(pts)
        parts["v"].append(v)
        parts["vol0"].append(np.full(n, volume))
        parts["mass"].append(np.full(n, volume * material.rho))
        parts["material"].append(np.full(n, names.index(body.material), dtype=np.int32))
        parts["C"].append(np.broadcast_to(grad, (n, dim, dim)))
    return make_particles(scene, **{k: np.concatenate(v) for k, v in parts.items()})


def make_particles(scene, x, v, mass, vol0, material, C):
    """A :class:`~mpmref.state.Particles` of the scene's dtype with the fields the scene needs: ``C`` (given)
    for affine schemes, ``F`` at the identity, ``J`` and ``Jp`` at one, PolyPIC's higher modes at zero."""
    n, dim, dtype = len(x), scene.dim, scene.dtype
    eye = np.eye(dim, dtype=dtype)
    return Particles(
        x=x.astype(dtype), v=v.astype(dtype), mass=mass.astype(dtype), vol0=vol0.astype(dtype), material=material,
        C=np.ascontiguousarray(C, dtype=dtype) if scene.transfer.affine else None,  # one kernel layout
        F=np.broadcast_to(eye, (n, dim, dim)).copy() if scene.tracks("F") else None,
        J=np.ones(n, dtype=dtype) if scene.tracks("J") else None,
        Jp=np.ones(n, dtype=dtype) if scene.tracks("Jp") else None,
        modes=_zero_modes(scene, n) if scene.transfer.polypic else None,
    )


def _zero_modes(scene, n):
    """PolyPIC higher-mode coefficients, all zero (the initial field is at most affine)."""
    m = len(higher_modes(scene.dim, scene.kernel.support))
    return np.zeros((n, m, scene.dim), dtype=scene.dtype)
