r"""What a frame is worth, material by material: the global statistics ``mpmref compare`` judges a run by.

For the particles of each material (masses :math:`m_p` from the start, :math:`M = \sum_p m_p`), at each frame:

* ``com_x``, ``com_y`` [, ``com_z``]: the centre of mass :math:`\sum_p m_p x_p / M`;
* ``q05_a``, ``q50_a``, ``q95_a``, ``min_a``, ``max_a``: the 5 %, 50 % and 95 % quantiles of the positions along each
  axis and the bounding box;
* with velocities: ``momentum_a`` :math:`\sum_p m_p v_p`; ``angular_momentum`` (2D; ``angular_momentum_a`` in 3D)
  :math:`\sum_p m_p (x_p - c) \times v_p` about the domain's centre :math:`c`; ``kinetic_energy``
  :math:`\tfrac12 \sum_p m_p |v_p|^2`;
* with the deformation: ``J_mean``, ``J_min``, ``J_max`` of the volume ratio :math:`J = V/V^0` (the fluid's
  :math:`J`, :math:`\det F` of an elastic solid, :math:`\det F\,J_P` of a plastic one; a frame's ``J`` array is read
  as that ratio, as ``mpmref run`` writes it) and ``Jp_mean``, ``Jp_min``, ``Jp_max`` of the plastic ones.

A statistic is named ``material:statistic`` (``water:kinetic_energy``). Each has a *scale*, the size of its
round-off: the domain's extent :math:`L` for positions, :math:`M V` for momenta, :math:`M L V` for angular momenta,
:math:`M V^2` for the kinetic energy and 1 for volume ratios, with :math:`V` the run's speed scale
(:func:`scales`).
"""

import numpy as np

from mpmref.physics.materials import determinant

AXES = "xyz"
QUANTILES = (0.05, 0.5, 0.95)


def volume_ratio(fields, material):
    r""":math:`J = V/V^0` of a material's particles from a frame's ``fields``: ``J`` for the fluid; for a solid,
    :math:`\det F` (times ``Jp`` for a plastic one) where ``F`` is there, else the frame's own ``J``; ``None`` when the
    frame has neither."""
    if material.tracks == "J" or "F" not in fields:
        return fields.get("J")
    J = determinant(fields["F"])
    return J * fields["Jp"] if getattr(material, "plastic", False) and "Jp" in fields else J


def material_statistics(x, fields, mass, material, centre):
    """``{statistic: value}`` of one material's particles (module docstring), from positions ``x`` (n, d), the
    ``fields`` the frame has (``v``, ``F``, ``J``, ``Jp``, each with those particles' rows) and masses ``mass``."""
    d = x.shape[1]
    total = float(mass.sum())
    stats = {}
    com = mass @ x / total
    for a in range(d):
        stats[f"com_{AXES[a]}"] = com[a]
        for q, value in zip(QUANTILES, np.quantile(x[:, a], QUANTILES)):
            stats[f"q{round(100 * q):02d}_{AXES[a]}"] = value
        stats[f"min_{AXES[a]}"], stats[f"max_{AXES[a]}"] = x[:, a].min(), x[:, a].max()
    if "v" in fields:
        v = fields["v"]
        momentum = mass @ v
        for a in range(d):
            stats[f"momentum_{AXES[a]}"] = momentum[a]
        r = x - centre
        if d == 2:
            stats["angular_momentum"] = mass @ (r[:, 0] * v[:, 1] - r[:, 1] * v[:, 0])
        else:
            moment = mass @ np.cross(r, v)
            for a in range(3):
                stats[f"angular_momentum_{AXES[a]}"] = moment[a]
        stats["kinetic_energy"] = 0.5 * mass @ np.sum(v * v, axis=1)
    for name, values in (("J", volume_ratio(fields, material)), ("Jp", fields.get("Jp"))):
        if values is not None and (name == "J" or getattr(material, "plastic", False)):
            stats.update({f"{name}_mean": values.mean(), f"{name}_min": values.min(), f"{name}_max": values.max()})
    return {k: float(v) for k, v in stats.items()}


def frame_statistics(scene, x, fields, mass, material):
    """``{"material:statistic": value}`` of a frame, every material of ``scene`` with particles (``material``: each
    particle's index into the scene's materials; ``x``, ``fields``, ``mass`` in the same row order)."""
    centre = scene.grid.origin + 0.5 * np.asarray(scene.grid.cells) * scene.grid.dx
    stats = {}
    for index, (name, law) in enumerate(scene.materials.items()):
        rows = material == index
        if rows.any():
            own = {k: v[rows] for k, v in fields.items()}
            stats.update({f"{name}:{k}": v for k, v in material_statistics(x[rows], own, mass[rows], law,
                                                                             centre).items()})
    return stats


def extent(scene):
    """The largest extent of the scene's domain, :math:`L`."""
    return float(np.max(np.asarray(scene.grid.cells)) * scene.grid.dx)


def scales(scene, names, mass, material, speed):
    """The round-off scale of each statistic of ``names`` (module docstring): ``speed`` is the run's speed scale
    :math:`V`, ``mass`` and ``material`` the particles' masses and material indices."""
    length = extent(scene)
    material_mass = {name: float(mass[material == k].sum()) for k, name in enumerate(scene.materials)}
    out = []
    for name in names:
        owner, statistic = name.split(":")
        M = material_mass[owner]
        if statistic.startswith("momentum"):
            out.append(M * speed)
        elif statistic.startswith("angular_momentum"):
            out.append(M * length * speed)
        elif statistic == "kinetic_energy":
            out.append(M * speed**2)
        elif statistic.startswith(("J", "Jp")):
            out.append(1.0)
        else:
            out.append(length)
    return np.array(out)


def speed_scale(scene, speeds):
    r"""The run's speed scale :math:`V`: the largest rms particle speed of ``speeds`` (one per frame), or the free-fall
    speed across the domain :math:`\sqrt{|g| L}` where that is larger (a run that starts at rest), and at least
    :math:`L` per second (a run with neither motion nor gravity)."""
    length = extent(scene)
    return max(max(speeds, default=0.0), float(np.sqrt(np.linalg.norm(scene.gravity) * length)), length)
