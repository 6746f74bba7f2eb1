"""Table 2 of the talk: P2G and G2P time of classic MPM and MLS-MPM on the 8-particles-per-cell block.

Each backend times four stages on the same particles: ``prepare`` (what P2G and G2P of one step share:
the kernel stencil for NumPy, the sort into blocks for Numba), ``stress`` (the Kirchhoff stress alone),
then ``p2g`` (which includes the stress) and ``g2p`` given that preparation, as a step runs them: the fused P2G
(``p2g_fused``, the force folded into the momentum) where the backend has it, for both methods, so that each is as
fast as the backend makes it. The grid velocities for G2P come from one untimed grid update after P2G. Besides the
P2G and G2P ratios, ``p2g_minus_stress`` compares the transfer part of P2G (median P2G minus median stress): the
stress is the same work for both methods and can hide the transfer's saving. ``predicted_p2g`` and
``predicted_g2p`` are the ratios the kernels' operation counts predict (:mod:`.opcount`), the P2G one with the
measured stress included.
"""

from ..backends import make_backend
from ..backends.base import FUSED_BACKEND_STAGES
from .memory import memory_probe
from .opcount import counts, predicted_ratio
from .scenes import TABLE2_MATERIAL, TABLE2_METHODS, TABLE2_PAD, table2_particles, table2_scene
from .timing import measure, set_threads, thread_counts

TABLE2_STAGES = ("prepare", "stress", "p2g", "g2p")


def run_table2(cells, backends, threads, dtypes, repeats, memory=True, log=print, dim=3):
    """Time every stage for each dtype, method (``mpm``, ``mls``), backend and thread count.

    Returns the ``table2`` section of the benchmark JSON (``table2_2d`` with ``dim = 2``): ``setup``,
    ``timings`` (one record per dtype, method, backend, threads and stage), ``ratios`` (MPM over MLS-MPM
    for P2G and G2P) and, if ``memory`` (3D only), the peak-memory probe of each backend and dtype at the
    largest thread count.
    """
    timings = []
    for dtype in dtypes:
        particles = table2_particles(table2_scene(cells, "mls", dtype, dim))
        for method in TABLE2_METHODS:
            scene = table2_scene(cells, method, dtype, dim)
            for backend in backends:
                log(f"table2: {dim}D {backend} {dtype} {method} ({particles.n} particles)")
                timings += time_stages(backend, scene, particles, threads, repeats, method)
    section = {"setup": table2_setup(cells, dim), "timings": timings, "ratios": table2_ratios(timings, dim),
               "operations": operation_counts(dim)}
    if memory and dim == 3:
        section["memory"] = [memory_probe(b, cells, dtype, max(thread_counts(b, threads)))
                             for b in backends for dtype in dtypes]
    return section


def operation_counts(dim):
    """Floating-point operations and particle bytes per particle of each method's fused P2G and G2P
    (:func:`.opcount.counts`), for the JSON document."""
    return [{"stage": stage, "method": method, "flops": c.flops, "bytes_float32": c.bytes,
             "bytes_float64": counts(dim, 8)[(stage, method)].bytes} for (stage, method), c in counts(dim).items()]


def table2_setup(cells, dim=3):
    """What the Table-2 figures were measured on."""
    return {"dim": dim, "cells_per_side": cells, "particles": 2**dim * cells**dim, "particles_per_cell": 2**dim,
            "offsets": "cell centre +- dx/4 on every axis", "kernel": "quadratic", "material": TABLE2_MATERIAL,
            "grid_nodes": (cells + 2 * TABLE2_PAD + 1) ** dim,
            "methods": {"mpm": "scheme apic, force classic (grad w)", "mls": "scheme mls (MLS-MPM)"}}


def time_stages(backend_name, scene, particles, threads, repeats, method):
    """Records of ``prepare``, ``p2g`` and ``g2p`` of one backend on one scene, per thread count."""
    backend = make_backend(backend_name, scene)
    dt = scene.time.dt
    records = []
    for k in thread_counts(backend_name, threads):
        set_threads(backend_name, k)
        prep, prepared = measure(lambda: backend.prepare(particles), repeats)
        stress, _ = measure(lambda: backend.stress(particles), repeats)
        p2g, grid_state = measure(lambda prepared=prepared: stepped_p2g(backend, particles, dt, prepared), repeats)
        v_grid, v_tilde = backend.grid_update(grid_state, dt)
        g2p, _ = measure(lambda v=v_grid, v_t=v_tilde, prepared=prepared: backend.g2p(particles, v, v_t, dt, prepared),
                         repeats)
        key = {"backend": backend_name, "threads": k, "dtype": str(scene.dtype), "method": method}
        records += [{**key, "stage": stage, **rec} for stage, rec in zip(TABLE2_STAGES, (prep, stress, p2g, g2p))]
    return records


def stepped_p2g(backend, particles, dt, prepared):
    """The P2G a step runs: the fused one where the backend has it (the force folded in), else the plain one."""
    fused = getattr(backend, FUSED_BACKEND_STAGES[0], None)
    return fused(particles, dt, prepared) if callable(fused) else backend.p2g(particles, prepared)


def table2_ratios(timings, dim=3):
    """MPM over MLS-MPM median time of P2G, G2P and P2G minus the stress, per backend, thread count and dtype.

    ``p2g_minus_stress`` is ``None`` when a median P2G is not above its median stress (timing noise).
    """
    median = {(t["backend"], t["threads"], t["dtype"], t["method"], t["stage"]): t["median_s"] for t in timings}
    ratios = []
    for key in sorted({k[:3] for k in median}):
        def of(method, stage, key=key):
            return median[(*key, method, stage)]

        transfer = [of(method, "p2g") - of(method, "stress") for method in ("mpm", "mls")]
        ratios.append({"backend": key[0], "threads": key[1], "dtype": key[2],
                       "p2g": of("mpm", "p2g") / of("mls", "p2g"), "g2p": of("mpm", "g2p") / of("mls", "g2p"),
                       "p2g_minus_stress": transfer[0] / transfer[1] if min(transfer) > 0 else None,
                       "predicted_p2g": predicted_ratio(dim, "p2g", of("mls", "p2g"), of("mls", "stress")),
                       "predicted_g2p": predicted_ratio(dim, "g2p")})
    return ratios
