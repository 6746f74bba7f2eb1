"""The parsers of the scene's settings sections: ``[grid]``, ``[method]`` (with its CPIC options), ``[boundary]``,
``[time]`` and ``[output]``. The sections of things (materials, bodies, emitters, colliders, rigid bodies) have
their own modules: :mod:`mpmref.scene.materials`, :mod:`mpmref.scene.bodies`, :mod:`mpmref.scene.rigid_bodies`.
"""

import numpy as np

from ..physics.boundary import BOUNDARY_TYPES
from ..physics.kernels import KERNELS
from ..state import Grid
from . import memory_limits
from .specs import BoundarySpec, CpicSpec, MethodSpec, OutputSpec, TimeSpec, WallSpec
from .validation import choice, fail, flag, integer, number, section, vector

SCHEMES = ("pic", "flip", "apic", "polypic", "mls")
FORCES = ("mls", "classic")
WALL_TYPES = BOUNDARY_TYPES + ("open",)
DOMAIN_EXIT_POLICIES = ("error", "clamp", "delete")
OUTPUT_FIELDS = ("velocity", "mass", "volume", "J", "stress", "pressure", "material")
#: what the grid output covers: the block-aligned box of the nodes with mass, or every node of the grid
GRID_REGIONS = ("active", "all")
AXES = "xyz"
STEPPINGS = ("sync", "async")
COUPLINGS = ("none", "cpic")
#: schemes CPIC is defined for (docs/cpic.md are written for PIC, APIC and MLS-MPM)
CPIC_SCHEMES = ("pic", "apic", "mls")
#: how a CPIC particle near several bodies gets its distance and normal (docs/cpic.md, "Per-body fit")
CPIC_FITS = ("single", "per_body")
#: the ``[method]`` keys of the CPIC coupling (:class:`~mpmref.scene.specs.CpicSpec`)
CPIC_KEYS = ("pushing_force", "penalty", "momentum_exact", "ghost_force", "cpic_fit")
ASYNC_TIME_KEYS = ("tick", "levels", "advection_cfl", "interface")
#: how level interfaces of asynchronous stepping exchange momentum (:mod:`mpmref.physics.interface`)
INTERFACES = ("conservative", "reference")


def parse_grid(g, dim, support):
    """The ``[grid]``: origin, size and one of ``dx`` or ``cells``, and the block size (a power of two that
    holds the kernel's ``support`` nodes)."""
    section(g, "grid", {"origin", "size", "dx", "cells", "block"})
    origin = vector(g, "origin", "grid", dim, default=[0.0] * dim)
    size = vector(g, "size", "grid", dim, required=True, positive=True)
    if ("dx" in g) == ("cells" in g):
        fail("grid.dx", g.get("dx"), "exactly one of 'grid.dx' or 'grid.cells' (cells along the first axis)")
    if "dx" in g:
        dx = number(g, "dx", "grid", lo=0.0, lo_open=True)
    else:
        dx = size[0] / integer(g, "cells", "grid", lo=4, hi=4096)
    cells_f = size / dx
    memory_limits.check_cells_per_axis(cells_f, *cell_size_field(g), dim)
    cells = np.rint(cells_f).astype(int)
    if np.any(np.abs(cells_f - cells) > 1e-9 * cells_f) or np.any(cells < 4):
        fail("grid.size", size.tolist(), f"a whole number (>= 4) of cells of dx = {dx} along every axis")
    block = integer(g, "block", "grid", default=4, lo=1, hi=256)
    if block & (block - 1) or block < support:
        fail("grid.block", block, f"a power of two >= {support} (the kernel support in nodes)")
    return Grid(origin=origin, dx=float(dx), cells=tuple(int(c) for c in cells), block=block)


def cell_size_field(g):
    """The grid field that set the cell size, and its value (for memory-limit messages)."""
    return ("grid.dx", g["dx"]) if "dx" in g else ("grid.cells", g["cells"])


def parse_method(m):
    """The ``[method]``: a :class:`MethodSpec` and the :class:`CpicSpec` of its coupling (``None`` without)."""
    section(m, "method", {"scheme", "force", "kernel", "flip_alpha", "velocity_gradient", "coupling", *CPIC_KEYS})
    scheme = choice(m, "scheme", "method", SCHEMES, default="mls")
    force = choice(m, "force", "method", FORCES, default="mls")
    gradient = choice(m, "velocity_gradient", "method", FORCES, default=force)
    kernel = choice(m, "kernel", "method", tuple(KERNELS), default="quadratic")
    if "flip_alpha" in m and scheme != "flip":
        fail("method.flip_alpha", m["flip_alpha"], f"only with method.scheme = 'flip' (scheme is '{scheme}')")
    alpha = number(m, "flip_alpha", "method", default=0.95 if scheme == "flip" else 0.0, lo=0.0, hi=1.0)
    spec = MethodSpec(scheme=scheme, force=force, kernel=kernel, flip_alpha=alpha, velocity_gradient=gradient)
    cpic = parse_coupling(m, scheme)
    _check_combination(spec)
    return spec, cpic


def parse_coupling(m, scheme):
    """The CPIC options of ``[method]`` (docs/cpic.md) as a :class:`CpicSpec`, or ``None`` for
    ``coupling = "none"`` (then none of them may be given)."""
    coupling = choice(m, "coupling", "method", COUPLINGS, default="none")
    if coupling == "none":
        for key in CPIC_KEYS:
            if key in m:
                fail(f"method.{key}", m[key], "only with method.coupling = 'cpic'")
        return None
    if scheme not in CPIC_SCHEMES:
        why = ("FLIP's increment needs every stencil node's velocity before and after forces, and a CPIC particle "
               "has no such node on the far side of a body" if scheme == "flip" else
               "PolyPIC's higher modes are projected from all stencil nodes, and ghost velocities at incompatible "
               "nodes define no modes")
        fail("method.scheme", scheme, f"one of {list(CPIC_SCHEMES)} with method.coupling = 'cpic' ({why})")
    exact = flag(m, "momentum_exact", "method", default=False)
    ghost_force = flag(m, "ghost_force", "method", default=True)
    if exact and scheme != "pic":
        fail("method.momentum_exact", exact, f"false with method.scheme = '{scheme}' (the exact variant needs PIC: "
             "the affine term is not given to bodies at incompatible nodes)")
    push = number(m, "pushing_force", "method", default=0.0 if exact else 2e4, lo=0.0)
    if exact and push != 0.0:
        fail("method.pushing_force", push, "0 with method.momentum_exact = true (the pushing force injects momentum "
             "that no body receives)")
    return CpicSpec(pushing_force=push, momentum_exact=exact, ghost_force=ghost_force,
                    penalty=number(m, "penalty", "method", default=0.0, lo=0.0),
                    fit=choice(m, "cpic_fit", "method", CPIC_FITS, default="single"))


def _check_combination(spec):
    """Refuse combinations of scheme, force and kernel that have no consistent discretisation."""
    if spec.scheme == "mls" and spec.force == "classic":
        fail("method.force", "classic", "'mls' with method.scheme = 'mls' (MLS-MPM is the APIC transfer with "
             "the MLS force; for APIC with the classic force use scheme = 'apic', force = 'classic')")
    if spec.kernel == "linear" and spec.scheme in ("apic", "polypic", "mls"):
        fail("method.kernel", "linear", f"'quadratic' or 'cubic' with method.scheme = '{spec.scheme}' (an affine "
             "scheme needs a constant inertia D_p, which the linear hat does not have)")
    for key in ("force", "velocity_gradient"):
        if spec.kernel == "linear" and getattr(spec, key) == "mls":
            fail(f"method.{key}", "mls", "'classic' with method.kernel = 'linear' (the MLS force and velocity "
                 "gradient need a constant D_p = k dx^2 I; the linear hat's D_p varies with position and is "
                 "singular on nodes)")


def parse_boundary(bd, dim, grid):
    """The ``[boundary]``: band width, a wall (type, friction) on each face of the domain, domain-exit policy."""
    section(bd, "boundary", {"width", "type", "friction", "walls", "domain_exit"})
    width_max = min(grid.cells) // 2 - 1
    width = integer(bd, "width", "boundary", default=min(3, width_max), lo=0, hi=width_max)
    default_type = choice(bd, "type", "boundary", WALL_TYPES, default="separate")
    default_mu = number(bd, "friction", "boundary", default=0.0, lo=0.0)
    names = [f"{AXES[a]}_{side}" for a in range(dim) for side in ("min", "max")]
    walls_in = bd.get("walls", {})
    section(walls_in, "boundary.walls", set(names))
    walls = {}
    for name in names:
        w = walls_in.get(name, {})
        path = f"boundary.walls.{name}"
        section(w, path, {"type", "friction"})
        walls[name] = WallSpec(type=choice(w, "type", path, WALL_TYPES, default=default_type),
                               friction=number(w, "friction", path, default=default_mu, lo=0.0))
    exit_policy = choice(bd, "domain_exit", "boundary", DOMAIN_EXIT_POLICIES, default="error")
    return BoundarySpec(width=width, walls=walls, domain_exit=exit_policy)


def parse_time(t):
    """The ``[time]``: a fixed step or a CFL number, the run's length, and the asynchronous settings."""
    section(t, "time", {"dt", "cfl", "steps", "t_end", "stepping", *ASYNC_TIME_KEYS})
    stepping = choice(t, "stepping", "time", STEPPINGS, default="sync")
    if stepping == "sync":
        for key in ASYNC_TIME_KEYS:
            if key in t:
                fail(f"time.{key}", t[key], "only with time.stepping = 'async'")
    elif "dt" in t:
        fail("time.dt", t["dt"], "absent with time.stepping = 'async' (each block's step comes from time.cfl; "
             "time.levels = 0 with time.tick = dt gives one fixed step)")
    if ("dt" in t) == ("cfl" in t):
        fail("time.dt", t.get("dt"), "exactly one of 'time.dt' (fixed step) or 'time.cfl' (CFL number)")
    dt = number(t, "dt", "time", lo=0.0, lo_open=True)
    cfl = number(t, "cfl", "time", lo=0.0, hi=10.0, lo_open=True)
    if "steps" in t and "t_end" in t:
        fail("time.steps", t["steps"], "either 'time.steps' or 'time.t_end', not both")
    steps = integer(t, "steps", "time", lo=0)
    t_end = number(t, "t_end", "time", lo=0.0)
    if stepping == "sync":
        return TimeSpec(dt=dt, cfl=cfl, steps=steps, t_end=t_end)
    return TimeSpec(dt=None, cfl=cfl, steps=steps, t_end=t_end, stepping="async",
                    tick=number(t, "tick", "time", default=1e-6, lo=0.0, lo_open=True),
                    levels=integer(t, "levels", "time", default=13, lo=0, hi=30),
                    advection_cfl=number(t, "advection_cfl", "time", default=1.0, lo=0.0, hi=10.0, lo_open=True),
                    interface=choice(t, "interface", "time", INTERFACES, default="conservative"))


def parse_output(o, time):
    """The ``[output]``: how often frames and checkpoints (``every``) and diagnostics rows (``diagnostics_every``,
    by default ``every``) are written, which particle fields, whether grid fields and checkpoints are written, and
    whether ``diagnostics.csv`` books the energy ledger (synchronous stepping only; ``time`` is the parsed
    ``[time]``)."""
    section(o, "output", {"every", "diagnostics_every", "fields", "grid", "grid_region", "checkpoint", "energy_ledger"})
    every = integer(o, "every", "output", default=50, lo=1)
    diagnostics_every = integer(o, "diagnostics_every", "output", default=every, lo=1)
    fields_ = o.get("fields", list(OUTPUT_FIELDS))
    if not isinstance(fields_, list) or any(f not in OUTPUT_FIELDS for f in fields_):
        fail("output.fields", fields_, f"a list drawn from {list(OUTPUT_FIELDS)}")
    grid, checkpoint = flag(o, "grid", "output", default=False), flag(o, "checkpoint", "output", default=True)
    region = o.get("grid_region", "active")
    if region not in GRID_REGIONS:
        fail("output.grid_region", region, f"one of {list(GRID_REGIONS)}")
    ledger = flag(o, "energy_ledger", "output", default=False)
    return OutputSpec(every=every, fields=tuple(fields_), grid=grid, checkpoint=checkpoint, grid_region=region,
                      energy_ledger=ledger, diagnostics_every=diagnostics_every)
