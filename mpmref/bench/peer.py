r"""Peer comparison: our Taichi kernels (:mod:`mpmref.peers.taichi_mpm88`) against mpmref on the same scene.

Both start from the same particles sampled by mpmref, run the same number of steps at the same thread
count in float32, and are timed the same way (median of repeats, the first call apart). Then the
centres of mass of their final states are compared.

Why the centre of mass, and its bound
-------------------------------------
Individual particle paths in a fluid are chaotic: round-off differences between two codes grow
exponentially, so comparing particles after many steps says nothing. The centre of mass does not share
this: P2G and G2P conserve momentum and the internal forces sum to zero
(:math:`\sum_i w_{ip}(x_i - x_p) = 0`), so as long as no particle's stencil reaches a wall band the mean
velocity after step :math:`k` is exactly :math:`\bar v_0 + k \Delta t g` whatever the particles do, and
the two codes differ in :math:`\bar x` by round-off only. Per step and per code (unit round-off
:math:`\varepsilon/2`):

* the position update :math:`x_p + \Delta t v_p` rounds by at most :math:`\tfrac{\varepsilon}{2} X`,
  :math:`X = \max |x_p|`;
* the velocity passes through P2G's momentum and mass sums and G2P's sum (:math:`3^d` terms each) and
  a few single operations: at most :math:`\kappa \varepsilon V` with :math:`\kappa = 3 \cdot 3^d + 3`
  and :math:`V = \max |v_p| + \sqrt d\, \tfrac32 \Delta x \max \lVert C_p \rVert_F` (the largest node
  velocity a particle sees); velocities are carried from step to step, so after :math:`k` steps the
  error is at most :math:`k \kappa \varepsilon V`.

Summing over :math:`N` steps and doubling for the two codes:

.. math::

    |\bar x^{\rm mpmref} - \bar x^{\rm peer}|_\infty
    \le N \varepsilon X + N (N + 1)\, \Delta t\, \kappa\, \varepsilon V .

``free_flight`` says whether the final states keep every stencil off the wall bands; when it is false
the bound does not apply and ``agree`` is ``None``.
"""

import numpy as np

from ..scene.sampling import sample_particles
from .throughput import time_steps
from .timing import measure, thread_counts

PEER_DTYPE = "float32"
INSTALL_HINT = "install the optional extra: pip install 'mpmref[bench]' (taichi==1.7.4)"


def load_taichi_peer():
    """The peer module, or ``None`` and the reason it cannot be imported."""
    try:
        from ..peers import taichi_mpm88
    except ImportError as exc:
        return None, f"Taichi is not importable ({exc}); {INSTALL_HINT}"
    return taichi_mpm88, None


def run_peer(cases, backends, threads, repeats, steps, log=print):
    """The ``peer`` section of the benchmark JSON (``available`` false with a ``message`` without Taichi).

    mpmref runs on every backend of ``backends`` other than NumPy (NumPy alone if it is the only one,
    on one thread).
    """
    peer, message = load_taichi_peer()
    if peer is None:
        return {"available": False, "message": message}
    mine = [b for b in backends if b != "numpy"] or ["numpy"]
    results = []
    for k in threads:
        at_k = [b for b in mine if k in thread_counts(b, threads)]
        if not at_k:
            continue
        peer.init(k, PEER_DTYPE)
        for case in cases:
            scene = case.scene(PEER_DTYPE)
            particles = sample_particles(scene)
            log(f"peer: {case.name}, taichi and {', '.join(at_k)} on {k} thread(s) ({particles.n} particles)")
            theirs, their_state = time_peer(peer, scene, particles, repeats, steps)
            for backend in at_k:
                records, final = time_steps(backend, scene, particles, [k], repeats, steps)
                row = {"case": case.name, "particles": particles.n, "threads": k, "backend": backend,
                       "mpmref": records[0], "taichi": theirs,
                       "ratio": records[0]["particle_steps_per_s"] / theirs["particle_steps_per_s"]}
                results.append({**row, **agreement(scene, particles, final, their_state, steps)})
    return {"available": True, "peer": "taichi", "version": peer.VERSION, "dtype": PEER_DTYPE,
            "steps": steps, "results": results}


def time_peer(peer, scene, particles, repeats, steps):
    """Timing record of the Taichi peer (whole steps) and its final state (``x, v, C, J``)."""
    sim = peer.TaichiFluid(scene, particles)

    def reload():
        sim.load(particles)
        return ()

    rec, _ = measure(lambda: sim.run(steps), repeats, setup=reload, first=lambda: sim.run(1))
    rec["particle_steps_per_s"] = particles.n * steps / rec["median_s"]
    return rec, sim.state()


def agreement(scene, initial, final, their_state, steps):
    """Centre-of-mass difference of the two final states, its round-off bound, and whether it holds."""
    mass = initial.mass.astype(np.float64)
    diff = float(np.abs(centre_of_mass(final.x, mass) - centre_of_mass(their_state["x"], mass)).max())
    states = [initial.arrays(), final.arrays(), their_state]
    bound = mean_position_bound(scene, states, steps)
    flight = clear_of_walls(scene, final.x) and clear_of_walls(scene, their_state["x"])
    return {"mean_position_difference": diff, "bound": bound, "free_flight": flight,
            "agree": diff <= bound if flight else None}


def centre_of_mass(x, mass):
    return (mass[:, None] * x.astype(np.float64)).sum(axis=0) / mass.sum()


def roundoff_bound(steps, dt, eps, x_max, v_scale, dim):
    r"""The round-off bound of the module doc, :math:`N\varepsilon X + N(N+1)\Delta t\,\kappa\varepsilon V`."""
    kappa = 3 * 3**dim + 3
    return steps * eps * x_max + steps * (steps + 1) * dt * kappa * eps * v_scale


def mean_position_bound(scene, states, steps):
    """:func:`roundoff_bound` with ``X`` and ``V`` the largest over ``states`` (dicts with ``x, v, C``)."""
    d, dx = scene.dim, scene.grid.dx
    x_max = max(float(np.abs(s["x"]).max()) for s in states)
    v_scale = max(float(np.abs(s["v"]).max()) + np.sqrt(d) * 1.5 * dx * frobenius_max(s["C"]) for s in states)
    return float(roundoff_bound(steps, scene.time.dt, np.finfo(scene.dtype).eps, x_max, v_scale, d))


def frobenius_max(C):
    return float(np.sqrt((C.astype(np.float64) ** 2).sum(axis=(1, 2))).max())


def clear_of_walls(scene, x):
    """Whether no particle's quadratic stencil reaches a node of a wall band (nodes within ``width``)."""
    xi = (x.astype(np.float64) - scene.grid.origin) / scene.grid.dx
    width, cells = scene.boundary.width, np.array(scene.grid.cells)
    return bool(np.all(xi >= width + 0.5) and np.all(xi < cells - width - 0.5))
