"""The GPU backend object: the reference's stages as numba-cuda kernels, the particles resident on the device."""

from functools import cached_property, wraps
from typing import NamedTuple

import numpy as np

from ...physics.materials import material_groups
from ...physics.polypic import higher_modes
from ...state import GridState, Particles
from ..base import serial_context, wall_table
from ..capabilities import Implements
from ..pointwise.grid import collider_table
from ..pointwise.laws import laws_of, parameter_table
from ..residency import ArrayPool, Summary
from .kernels import Config, Kernels
from .particles import CHECKED_FIELDS, summary_size
from .runtime import device_name, require_device
from .sort import INDEX, exclusive_scan

#: P2G modes: ``gather`` (the default: no float atomics, the same bits every run) and ``atomic`` (opt-in)
P2G_MODES = ("gather", "atomic")


def either_memory(stage=None, *, outputs=True):
    """A stage written for the backend's own arrays, run on host inputs too: inputs whose first is on the host are
    copied to the device, and the outputs (``outputs``) back (how the conformance harness and a run with step hooks
    call the stages; a resident run hands the device arrays from one stage to the next)."""

    def either(stage):
        @wraps(stage)
        def run(self, first, *args, **kwargs):
            if self.holds(first.x if isinstance(first, Particles) else first.mass):
                return stage(self, first, *args, **kwargs)
            out = stage(self, *(self._on_device(a) for a in (first, *args)), **kwargs)
            return self._on_host(out) if outputs else out

        return run

    return either if stage is None else either(stage)


class Prepared(NamedTuple):
    """What P2G and G2P of one step share: the particles on the device, their cells (``keys``), the box of occupied
    cells (``box``) and, for the gathering P2G, each cell's first slot (``start``) and the particles in cell order
    (``order``) (:mod:`.sort`). Valid until the backend's next :meth:`CudaBackend.prepare`."""

    particles: Particles
    keys: object
    box: object
    start: object
    order: object


class DeviceNodes:
    """The ``layout`` of a :class:`~mpmref.state.GridState` whose arrays live on the GPU: dense, C order;
    :meth:`~mpmref.state.GridState.dense` copies them to the host and ``assign_dense`` back."""

    def __init__(self, grid):
        self.grid = grid

    @staticmethod
    def to_dense(array):
        return array.copy_to_host()

    @staticmethod
    def from_dense(array, out):
        out.copy_to_device(np.ascontiguousarray(array, dtype=out.dtype))
        return out

    @cached_property
    def node_index(self):
        """The multi-index of every row (every node, C order)."""
        return self.grid.node_indices()


class CudaBackend:
    """The stages of :mod:`mpmref.backends.base` as CUDA kernels (numba-cuda), for ``scene``; docs/gpu.md.

    Every stage takes host particles (NumPy arrays) or device particles (this backend's :meth:`to_device`) and
    returns the same kind: a run keeps them on the device (the backend is resident, :mod:`mpmref.backends.residency`),
    the conformance harness calls the stages on host arrays. Grid arrays are dense over every node in C order;
    a grid state on the device carries a :class:`DeviceNodes` layout. P2G gathers by node in a fixed order
    (``p2g="gather"``, the default: the same bits every run) or scatters with atomic adds (``p2g="atomic"``:
    reproducible only to round-off).

    The declaration :attr:`implements` refuses asynchronous stepping and rigid bodies before any work; making the
    backend without numba-cuda or without a GPU raises :class:`~mpmref.errors.BackendError` naming what is missing.
    """

    name = "cuda"
    implements = Implements(stepping=("sync",), rigid_bodies=False)
    running = staticmethod(serial_context)

    def __init__(self, scene, p2g="gather"):
        if p2g not in P2G_MODES:
            raise ValueError(f"p2g = {p2g!r}: allowed {list(P2G_MODES)}")
        self.cuda = require_device()
        self.scene, self.p2g_mode = scene, p2g
        self.config = Config.of(scene)
        self.kernels = Kernels(self.config)
        self.dtype = np.dtype(scene.dtype)
        grid, d = scene.grid, scene.dim
        self.dim, self.dx, self.n_nodes = d, float(grid.dx), grid.n_nodes
        self.inertia = 0.0 if scene.kernel.inertia_factor is None else scene.kernel.inertia_factor * self.dx**2
        self.flip_alpha = float(scene.transfer.flip_alpha)
        to = self._constant
        self.origin = to(np.asarray(grid.origin, dtype=self.dtype))
        self.origin64 = to(np.asarray(grid.origin, dtype=np.float64))
        self.node_shape = to(np.array(list(grid.node_shape) + [1] * (3 - d), dtype=np.int64))
        self.gravity = to(np.asarray(scene.gravity, dtype=self.dtype))
        wall_type, wall_friction = wall_table(scene.boundary, d)
        self.wall_type, self.wall_friction = to(wall_type), to(wall_friction.astype(self.dtype))
        self.colliders = to(collider_table(scene.colliders))
        self.rules, self.params = to(laws_of(scene.material_list)[1]), to(parameter_table(scene.material_list))
        self.plastic = any(m.plastic for m in scene.material_list)
        modes = higher_modes(d, scene.kernel.support) if scene.transfer.polypic else np.zeros((0, d))
        self.mode_index = to(np.ascontiguousarray(modes, dtype=np.int64))
        self.pool = ArrayPool(self.cuda.device_array, self.dtype)
        self._device_array = type(self.cuda.device_array(0))
        self._scratch, self._empty = {}, {}

    # ------------------------------------------------------------------ memory
    def _constant(self, array):
        return self.cuda.to_device(np.ascontiguousarray(array))

    def _take(self, kind, shape):
        """A device array for a stage's output, from the backend's :class:`~mpmref.backends.residency.ArrayPool`."""
        return self.pool.take(kind, shape)[0]

    def _work(self, kind, shape, dtype=INDEX):
        """A device array of the backend's own, reused by every call (a stage's intermediate)."""
        key = (kind, shape, np.dtype(dtype).str)
        if key not in self._scratch:
            self._scratch[key] = self.cuda.device_array(shape, dtype)
        return self._scratch[key]

    def _none(self, *shape, dtype=None):
        """An empty device array (no rows) of ``shape``: what a kernel gets for a field the scene does not have."""
        key = (shape, np.dtype(dtype or self.dtype).str)
        if key not in self._empty:
            self._empty[key] = self.cuda.device_array(shape, dtype or self.dtype)
        return self._empty[key]

    def _or_none(self, array, *shape):
        return array if array is not None else self._none(*shape)

    # ------------------------------------------------------------------ residency (mpmref.backends.residency)
    def holds(self, array):
        """Whether ``array`` is in this GPU's memory (one of numba-cuda's device arrays, or its simulator's): the one
        test of where an array lives."""
        return isinstance(array, self._device_array)

    def to_device(self, particles):
        """The host particles with every array on the GPU but the stable ``id``."""
        arrays = {name: a.astype(np.int32) if name == "material" else a for name, a in particles.arrays().items()}
        return Particles(**{name: a if name == "id" else self.cuda.to_device(np.ascontiguousarray(a))
                            for name, a in arrays.items()})

    def to_host(self, particles):
        """The device particles as NumPy arrays (the ``id`` is on the host already)."""
        return Particles(**{name: a if name == "id" else a.copy_to_host() for name, a in particles.arrays().items()})

    def host_array(self, array):
        """``array`` on the host: a copy of a device array, any other as it is."""
        return array.copy_to_host() if self.holds(array) else array

    def _on_device(self, value):
        """Host particles, a host grid state or a NumPy array in the GPU's memory; anything else as it is."""
        if isinstance(value, Particles):
            return self.to_device(value)
        if isinstance(value, GridState):
            return GridState(**{name: self._on_device(a) for name, a in value.node_arrays().items()})
        return self.cuda.to_device(np.ascontiguousarray(value)) if isinstance(value, np.ndarray) else value

    def _on_host(self, value):
        """A stage's outputs (particles, a grid state, arrays, a tuple of them) on the host."""
        if isinstance(value, Particles):
            return self.to_host(value)
        if isinstance(value, GridState):
            return value.dense()
        if isinstance(value, tuple):
            return tuple(self._on_host(v) for v in value)
        return self.host_array(value)

    @cached_property
    def _summary_start(self):
        """What a summary's maxima start from before the reduction (host, -inf each)."""
        return np.full(summary_size(self.dim), -np.inf)

    def summarize(self, particles, previous=None):
        """The :class:`~mpmref.backends.residency.Summary` of the device particles, reduced on the GPU (five numbers and
        a flag per field come back): non-finite fields, extent, largest velocity change since ``previous``, largest
        signal speed."""
        p, d = particles, self.dim
        out = self._work("summary", (summary_size(d),), np.float64)
        out.copy_to_device(self._summary_start)  # every maximum starts at -inf; the device array is the backend's own
        old = previous.v if previous is not None else p.v
        self.kernels.particles.summarize(p.n, p.x, p.v, old, self._or_none(p.C, 0, d, d), self._or_none(p.F, 0, d, d),
                                         self._or_none(p.J, 0), self._or_none(p.Jp, 0),
                                         self._or_none(p.modes, 0, 0, d), p.material, self.rules, self.params, out)
        got = out.copy_to_host()
        flags = len(CHECKED_FIELDS)
        return Summary(nonfinite=tuple(f for f, bad in zip(CHECKED_FIELDS, got[:flags]) if bad > 0),
                       lower=-got[flags:flags + d], upper=got[flags + d:flags + 2 * d],
                       velocity_change=max(float(got[-2]), 0.0), signal_speed=max(float(got[-1]), 0.0))

    # ------------------------------------------------------------------ stages
    @either_memory(outputs=False)
    def prepare(self, particles):
        """The particles on the device and, for the gathering P2G, sorted by cell (:mod:`.sort`): a
        :class:`Prepared`."""
        p = particles
        n, N = p.n, self.n_nodes
        sort = self.kernels.sort
        keys, rank = self._work("keys", (n,)), self._work("rank", (n,))
        count, box = self._work("count", (N + 1,)), self._work("box", (6,))
        sort.reset(N + 1, count, box)
        sort.cell_keys(n, p.x, self.origin, self.dx, self.node_shape, keys, count, rank, box)
        if self.p2g_mode == "atomic":
            return Prepared(p, keys, box, None, None)
        start = exclusive_scan(sort, count, self._work("start", (N + 1,)), lambda kind, m: self._work(kind, (m,)))
        order = self._work("order", (n,))
        sort.scatter(n, keys, rank, start, order)
        sort.order_cells(N, start, order)
        return Prepared(p, keys, box, start, order)

    @either_memory
    def stress(self, particles):
        """Kirchhoff stress (n, d, d) of every particle by its material's law."""
        p, d = particles, self.dim
        tau = self._take("tau", (p.n, d, d))
        self.kernels.particles.stress(p.n, self._or_none(p.F, 0, d, d), self._or_none(p.J, 0),
                                      self._or_none(p.Jp, 0), p.material, self.rules, self.params, tau)
        return tau

    @either_memory
    def p2g(self, particles, prepared=None, contact=None, classes=None):
        """Node mass, momentum and internal force (:mod:`~mpmref.backends.cuda.p2g`): a :class:`~mpmref.state.GridState`
        on the device for device particles, on the host for host particles. CPIC contact and particle classes are not
        implemented (scenes that need them are refused when the backend is made)."""
        if contact is not None or classes is not None:
            raise NotImplementedError("the cuda backend has no CPIC contact or particle classes")
        return self._p2g(particles, prepared, self.kernels.p2g, 0.0)

    @either_memory
    def p2g_fused(self, particles, dt, prepared=None):
        """P2G with the step's internal force folded into the momentum (:mod:`~mpmref.backends.cuda.p2g`; ``force`` is
        ``None``)."""
        return self._p2g(particles, prepared, self.kernels.p2g_fused, dt)

    def _p2g(self, particles, prepared, kernels, dt):
        prep = prepared if prepared is not None else self.prepare(particles)
        p, n, N, d = prep.particles, prep.particles.n, self.n_nodes, self.dim
        fused = kernels is self.kernels.p2g_fused
        rows = self._work("rows", (n, kernels.row.width), self.dtype)
        order = prep.order if prep.order is not None else self._identity(n)
        kernels.prelude(n, order, p.x, p.v, self._or_none(p.C, 0, d, d), self._or_none(p.modes, 0, 0, d),
                        self._or_none(p.F, 0, d, d), self._or_none(p.J, 0), self._or_none(p.Jp, 0), p.mass, p.vol0,
                        p.material, self.rules, self.params, self.mode_index, self.origin, self.dx, self.inertia, dt,
                        rows)
        mass, momentum = self._take("grid_mass", (N,)), self._take("grid_momentum", (N, d))
        force = self._none(0, d) if fused else self._take("grid_force", (N, d))
        if prep.order is None:
            kernels.clear(N, mass, momentum, force)
            kernels.scatter(n, prep.keys, rows, self.node_shape, self.dx, mass, momentum, force)
        else:
            kernels.gather(N, prep.start, prep.box, rows, self.node_shape, self.dx, mass, momentum, force)
        return GridState(mass=mass, momentum=momentum, force=None if fused else force,
                         layout=DeviceNodes(self.scene.grid))

    def _identity(self, n):
        """The particles in their own order (the atomic P2G's rows)."""
        key = ("identity", n)
        if key not in self._scratch:
            self._scratch[key] = self.cuda.to_device(np.arange(n, dtype=INDEX))
        return self._scratch[key]

    @either_memory
    def grid_update(self, grid_state, dt, time=0.0):
        """Node velocities after forces, gravity, walls and colliders, ``(v, v_tilde)``
        (:mod:`~mpmref.backends.cuda.grid_update`), on the device for a device grid state, on the host for a host one;
        ``v_tilde`` is ``None`` after a fused P2G."""
        d, N = self.dim, grid_state.mass.shape[0]
        folded = grid_state.force is None
        mass, momentum = grid_state.mass, grid_state.momentum
        force = self._none(0, d) if folded else grid_state.force
        v = self._take("grid_v", (N, d))
        v_tilde = self._none(0, d) if folded else self._take("grid_v_tilde", (N, d))
        self.kernels.grid_update(N, mass, momentum, force, self.node_shape, float(dt), float(time), self.gravity,
                                 self.wall_type, self.wall_friction, int(self.scene.boundary.width), self.colliders,
                                 len(self.scene.colliders), self.origin64, self.dx, v, v_tilde)
        return v, None if folded else v_tilde

    @either_memory
    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        """New particles from the node velocities (:mod:`~mpmref.backends.cuda.g2p`): on the device for device
        particles, on the host for host particles. Kicks of conservative level interfaces are not implemented
        (asynchronous stepping is refused)."""
        if kicks is not None:
            raise NotImplementedError("the cuda backend has no asynchronous stepping")
        p = prepared.particles if prepared is not None else particles
        n, d = p.n, self.dim
        v_tilde = v_grid if v_tilde is None else v_tilde

        def output(name, *shape):
            return self._take(f"particles_{name}", shape) if getattr(p, name) is not None else self._none(0, *shape[1:])

        out = {"x": self._take("particles_x", (n, d)), "v": self._take("particles_v", (n, d)),
               "C": output("C", n, d, d), "F": output("F", n, d, d), "J": output("J", n),
               "modes": output("modes", n, *(p.modes.shape[1:] if p.modes is not None else (0, d)))}
        self.kernels.g2p(n, p.x, p.v, self._or_none(p.F, 0, d, d), self._or_none(p.J, 0), self.origin, self.dx,
                         self.inertia, float(dt), self.flip_alpha, self.mode_index, self.node_shape, v_grid, v_tilde,
                         out["x"], out["v"], out["C"], out["F"], out["J"], out["modes"])
        return particles.with_(**{name: a for name, a in out.items()
                                  if name in ("x", "v") or getattr(p, name) is not None})

    @either_memory
    def return_map(self, particles, wave_speed=None):
        """Plastic projection of the plastic materials' particles (:mod:`~mpmref.backends.cuda.materials`; a new state,
        the others' ``F`` and ``Jp`` copied). With ``wave_speed`` (float64, (n,), on the host or the device), each
        particle's wave speed :math:`c_p` in its new state written there too, by its material's law on the device
        (the ``wave_speeds`` kernel of :mod:`.particles`, after the projection; the reference and its equations:
        :meth:`mpmref.backends.numpy.backend.NumpyBackend.return_map`). The backend refuses asynchronous stepping,
        the one caller of this output; the conformance harness checks it."""
        new = particles
        if self.plastic and particles.Jp is not None:
            p = particles
            F, Jp = self._take("particles_F_plastic", p.F.shape), self._take("particles_Jp_plastic", p.Jp.shape)
            self.kernels.particles.return_map(p.n, p.F, p.Jp, p.material, self.rules, self.params, F, Jp)
            new = particles.with_(F=F, Jp=Jp)
        if wave_speed is not None:
            self._wave_speeds(new, wave_speed)
        return new

    def _wave_speeds(self, particles, out):
        """Each particle's wave speed into ``out`` (a host or device float64 array of a row per particle)."""
        p, d = particles, self.dim
        speeds = out if self.holds(out) else self._work("wave_speed", (p.n,), np.float64)
        self.kernels.particles.wave_speeds(p.n, self._or_none(p.F, 0, d, d), self._or_none(p.J, 0),
                                           self._or_none(p.Jp, 0), p.material, self.rules, self.params, speeds)
        if speeds is not out:
            out[:p.n] = speeds.copy_to_host()

    # ------------------------------------------------------------------ reports and warm-up
    def describe_execution(self):
        """How the kernels run, for summaries: the GPU and the P2G mode."""
        return f"{device_name()}, P2G by {self.p2g_mode}"

    def warm_up(self, particles, step, per_material=2):
        """Compile every kernel a step of this scene launches, before a timed run: ``step(backend, particles, dt,
        time)`` (:func:`mpmref.steppers.pipeline.substep`, passed in by the caller) on the device, on the first
        ``per_material`` particles of each material, with Δt = 0, and the run's summary; ``particles`` (host ones) are
        not modified."""
        keep = np.zeros(particles.n, dtype=bool)
        for _, idx in material_groups(self.scene.material_list, particles):
            keep[idx[:per_material]] = True
        subset = self.to_device(particles.select(keep))
        self.summarize(step(self, subset, 0.0, 0.0), subset)
