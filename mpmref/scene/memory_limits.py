"""Memory limits of a scene: estimate the bytes a scene needs before anything is allocated.

A scene is refused (:class:`~mpmref.errors.SceneError`) when its estimate exceeds
:data:`MEMORY_FRACTION` of the memory available on this machine, with the estimate and the limit in
the message. The estimate counts what one step of the NumPy reference holds at once (the Numba
backend holds less):

* per grid node, in float64 whatever the scene's dtype: mass, momentum, force, the scatter temporary
  of P2G, the grid velocity and its pre-wall copy ṽ (``2 + 5 d`` numbers, see :func:`bytes_per_node`);
* per particle: the fields the scene allocates (``x, v, mass, vol0, material`` and, when declared,
  ``C, F, J, Jp`` and PolyPIC's modes) three times over (the current state, the new one and the G2P
  accumulators), plus the stencil weights and the stress work arrays of one step
  (see :func:`bytes_per_particle`).

Particle counts are estimated from each body's bounding box: ``volume * ppc / dx**d`` for sampled
shapes (the sampler fills the bounding box before it cuts the shape out), ``count`` for random sampling
with a count, the number of points for a ``points`` body. A ``mesh`` body is not estimated: its size is
known only once its file is read.

The estimate errs on the safe side. Peak resident memory of one NumPy step, measured against it
(float64, fixed-corotated block): 2D MLS, 2.7 M particles on 513² nodes, 1167 MiB measured for 1529 MiB
estimated; 3D MLS, 3.7 M particles on 65³ nodes, 2842 for 3672 MiB; 3D PIC, 4.1 M particles on 201³
nodes, 3693 for 4288 MiB; 3D ``cells = 256`` with 125 particles, 2.4 GB measured (reported by users) for 2.3 GB.
"""

import math
import os

from ..errors import SceneError
from ..physics.polypic import higher_modes

#: the share of the available memory a scene may plan to use
MEMORY_FRACTION = 0.5
#: assumed available memory when neither /proc/meminfo nor os.sysconf can tell (4 GiB)
FALLBACK_AVAILABLE = 4 * 2**30
#: the smallest number of cells along an axis (see ``mpmref.scene.parsers.parse_grid``)
MIN_CELLS = 4


def available_memory():
    """Bytes of memory available to a new allocation, and where that figure came from.

    Reads ``MemAvailable`` from ``/proc/meminfo`` (Linux), else the free physical pages from
    ``os.sysconf``, else assumes :data:`FALLBACK_AVAILABLE`.

    Returns
    -------
    (int, str)
        The number of bytes and a short description of its source.
    """
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024, "MemAvailable in /proc/meminfo"
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"), "free pages from os.sysconf"
    except (OSError, ValueError, AttributeError):
        return FALLBACK_AVAILABLE, "an assumed 4 GiB (the available memory could not be read)"


def memory_limit():
    """The byte budget of one scene, and a description of how it was derived (for error messages)."""
    available, source = available_memory()
    limit = int(MEMORY_FRACTION * available)
    return limit, f"{MEMORY_FRACTION:.0%} of the {format_bytes(available)} available ({source})"


def format_bytes(n):
    """``n`` bytes as a short human figure, e.g. ``'2.3 GiB'``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.3g} EiB"


def bytes_per_node(dim, colliders=False):
    """Bytes per grid node during one step: ``2 + 5 d`` float64 numbers, ``+ 2 d`` with colliders.

    Mass and its scatter temporary (2), momentum, force, the momentum scatter temporary, the grid
    velocity and ṽ (``d`` each); colliders keep the node positions and their integer indices.
    """
    return 8 * (2 + 5 * dim + (2 * dim if colliders else 0))


def bytes_per_particle(dim, itemsize, spec):
    """Bytes per particle during one step.

    Parameters
    ----------
    dim : int
    itemsize : int          bytes of one number of the scene's dtype
    spec : TransferSpec     the resolved scheme (:mod:`mpmref.physics.scheme`): which of ``C``, ``F``, ``J``,
                            ``Jp`` and PolyPIC's modes are allocated, and the kernel support
    """
    support = spec.support
    numbers = 2 * dim + 2  # x, v, mass, vol0
    numbers += dim * dim * (spec.affine + spec.tracks_F)
    numbers += spec.tracks_J + spec.tracks_Jp
    if spec.polypic:
        numbers += len(higher_modes(dim, support)) * dim
    state = 3 * (numbers * itemsize + 4 + 8)  # current, new, G2P accumulators; int32 material ids, int64 ids
    work = 8 * (2 * dim * support + dim + 2 * dim * dim + 4 * dim)  # weights, base, stress, per-offset temporaries
    return state + work


def estimated_particles(body, dim, dx):
    """Particles a body will have (an upper estimate from its bounding box; 0 for a mesh body)."""
    p = body.params
    if body.shape == "points":
        return len(p["positions"])
    if p.get("count") is not None:
        return p["count"]
    if body.shape == "box":
        volume = math.prod(float(u - lo) for u, lo in zip(p["upper"], p["lower"]))
    elif body.shape in ("disk", "sphere"):
        volume = (2.0 * p["radius"]) ** dim
    else:
        return 0
    return math.ceil(volume / dx**dim * p["ppc"])


def check_cells_per_axis(cells, field, value, dim, colliders=False):
    """Refuse a grid with more cells along one axis than memory allows even with 4 cells on the others.

    Called before the cell counts are rounded to integers, so that a tiny ``dx`` is reported as such.

    Parameters
    ----------
    cells : sequence of float     ``size / dx`` per axis
    field, value : str, object    the scene field that set the cell size, and its value (for the message)
    dim : int
    """
    limit, how = memory_limit()
    max_nodes = limit // bytes_per_node(dim, colliders)
    per_axis = max(max_nodes // (MIN_CELLS + 1) ** (dim - 1) - 1, MIN_CELLS)
    worst = max(cells)
    if not worst <= per_axis:  # also refuses nan
        raise SceneError(field, value, f"at most {per_axis:,} cells along any axis in {dim}D (it gives "
                                       f"{worst:.4g} cells; the memory limit is {format_bytes(limit)}, {how})")


def check_scene_memory(scene_parts):
    """Refuse a scene whose estimated memory exceeds :func:`memory_limit`, naming the field to change.

    Parameters
    ----------
    scene_parts : dict
        ``dim``, ``dtype`` (numpy dtype), ``grid`` (Grid), ``transfer`` (TransferSpec), ``bodies`` (list of BodySpec),
        ``colliders`` (list), ``grid_field`` and ``grid_value`` (the grid field that set the cell size, and its value).
    """
    s = scene_parts
    limit, how = memory_limit()
    grid_bytes = s["grid"].n_nodes * bytes_per_node(s["dim"], bool(s["colliders"]))
    if grid_bytes > limit:
        max_nodes = limit // bytes_per_node(s["dim"], bool(s["colliders"]))
        raise SceneError(s["grid_field"], s["grid_value"],
                         f"a grid of at most {max_nodes:,} nodes (about {int(max_nodes ** (1 / s['dim']))} per axis "
                         f"in {s['dim']}D): {s['grid'].n_nodes:,} nodes need about {format_bytes(grid_bytes)}, "
                         f"more than the memory limit {format_bytes(limit)} ({how})")
    _check_particles(s, limit, grid_bytes, how)


def _check_particles(s, limit, grid_bytes, how):
    room = limit - grid_bytes
    per = bytes_per_particle(s["dim"], s["dtype"].itemsize, s["transfer"])
    counts = [estimated_particles(b, s["dim"], s["grid"].dx) for b in s["bodies"]]
    if sum(counts) * per <= room:
        return
    i = max(range(len(counts)), key=counts.__getitem__)
    body = s["bodies"][i]
    key = "count" if body.params.get("count") is not None else ("positions" if body.shape == "points" else "ppc")
    value = body.params[key] if key != "positions" else f"{counts[i]:,} points"
    raise SceneError(f"bodies[{body.index}].{key}", value,
                     f"at most {max(room // per, 0):,} particles in all: the scene's estimated {sum(counts):,} "
                     f"particles need about {format_bytes(sum(counts) * per)} beside the grid's "
                     f"{format_bytes(grid_bytes)}, more than the memory limit {format_bytes(limit)} ({how})")
