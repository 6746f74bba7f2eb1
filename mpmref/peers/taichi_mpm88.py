r"""Our own Taichi implementation of mpmref's fluid scenes (``mpm88`` and its 3D counterpart).

The peer of ``mpmref bench --vs taichi``. It is written from the equations of the NumPy reference
(:mod:`mpmref.backends.numpy.transfers`) for the one combination those scenes use, so that both codes
compute the same thing and differ only in round-off:

* quadratic B-spline stencil, :math:`\xi = (x_p - o)/\Delta x`, base node :math:`\lfloor \xi - 1/2 \rfloor`;
* weakly compressible fluid tracking :math:`J`: :math:`\tau_p = -K (J_p^{-\gamma} - 1) J_p\, I`;
* MLS-MPM P2G with the momentum and force fused into one affine matrix (Hu et al. 2018 Eq. 18 with
  APIC's momentum, Jiang et al. 2015 §5): every node receives :math:`w_{ip}(m_p v_p + A_p (x_i - x_p))`
  with :math:`A_p = m_p C_p - \Delta t\, V_p^0 \tau_p D_p^{-1}`, so that the node holds
  :math:`(mv)_i + \Delta t f_i`, :math:`D_p = \tfrac14 \Delta x^2`;
* grid update :math:`v_i = ((mv)_i + \Delta t f_i)/m_i + \Delta t g` on nodes with mass (zero elsewhere),
  then the ``separate`` wall projection with Coulomb friction on each wall's band of ``width`` nodes, walls
  in mpmref's order (x_min, x_max, y_min, ...) as :func:`mpmref.physics.boundary.project_velocity`;
* G2P: :math:`v_p = \sum_i w_{ip} v_i`, :math:`C_p = \sum_i w_{ip} v_i (x_i - x_p)^T D_p^{-1}`,
  :math:`J_p \leftarrow (1 + \Delta t \operatorname{tr} C_p) J_p`, :math:`x_p \leftarrow x_p + \Delta t v_p`.

Scenes outside this set are refused by :func:`check_scene` with a message naming what is unsupported.
Taichi is an optional dependency (the ``bench`` extra): importing this module imports it.
"""

import numpy as np
import taichi as ti

from ..errors import MpmrefError
from ..physics.materials import WeaklyCompressibleFluid

SUPPORTED_WALLS = ("separate", "open")
VERSION = ".".join(str(part) for part in ti.__version__)


def check_scene(scene):
    """Raise :class:`~mpmref.errors.MpmrefError` unless this peer implements ``scene`` exactly."""
    problems = []
    if len(scene.materials) != 1 or not isinstance(scene.material_list[0], WeaklyCompressibleFluid):
        problems.append("one material of type 'fluid'")
    if scene.method.scheme != "mls" or scene.method.kernel != "quadratic":
        problems.append("method.scheme = 'mls' with the quadratic kernel")
    if scene.colliders:
        problems.append("no colliders")
    if any(w.type not in SUPPORTED_WALLS for w in scene.boundary.walls.values()):
        problems.append(f"walls of type {list(SUPPORTED_WALLS)}")
    if scene.time.dt is None:
        problems.append("a fixed time.dt")
    if problems:
        raise MpmrefError(f"the Taichi peer cannot run scene '{scene.name}': it needs " + ", ".join(problems))


def init(threads, dtype):
    """(Re)start Taichi's CPU runtime with ``threads`` worker threads and ``dtype`` as its default float.

    Fields made before the call are released (``ti.reset``); build a new :class:`TaichiFluid` after it.
    """
    ti.reset()
    ti.init(arch=ti.cpu, cpu_max_num_threads=int(threads), default_fp=_taichi_float(dtype), log_level=ti.WARN)


def _taichi_float(dtype):
    return {np.dtype(np.float32): ti.f32, np.dtype(np.float64): ti.f64}[np.dtype(dtype)]


def _wall_list(scene):
    """``(axis, sign, friction)`` of every non-open wall, in mpmref's order; sign is the inward normal."""
    walls = []
    for a in range(scene.dim):
        for side, sign in (("min", 1), ("max", -1)):
            wall = scene.boundary.walls[f"{'xyz'[a]}_{side}"]
            if wall.type != "open":
                walls.append((a, sign, float(wall.friction)))
    return walls


@ti.data_oriented
class TaichiFluid:
    """The scene's particles and grid as Taichi fields, stepped by Taichi kernels.

    Parameters
    ----------
    scene : Scene
        A scene accepted by :func:`check_scene`; its dtype is the fields' dtype.
    particles : Particles
        Initial state (``x, v, C, J, mass, vol0``), copied into the fields.

    Notes
    -----

    Call :func:`init` first. ``step()`` launches the four kernels of one step; ``run(steps)`` steps and
    then waits for every kernel to finish (``ti.sync``); ``state()`` reads the particles back as NumPy arrays.
    """

    def __init__(self, scene, particles):
        check_scene(scene)
        grid, fluid = scene.grid, scene.material_list[0]
        self.real, self.np_real = _taichi_float(scene.dtype), np.dtype(scene.dtype)
        self.dim, self.dx, self.dt = scene.dim, float(grid.dx), float(scene.time.dt)
        self.inertia = scene.kernel.inertia_factor * self.dx * self.dx
        self.K, self.gamma = float(fluid.K), float(fluid.gamma)
        self.cells, self.width, self.walls = grid.cells, scene.boundary.width, _wall_list(scene)
        n, d = particles.n, self.dim
        self.x, self.v = ti.Vector.field(d, self.real, n), ti.Vector.field(d, self.real, n)
        self.C = ti.Matrix.field(d, d, self.real, n)
        self.J, self.mass, self.vol0 = (ti.field(self.real, n) for _ in range(3))
        self.grid_m = ti.field(self.real, grid.node_shape)
        self.grid_mv = ti.Vector.field(d, self.real, grid.node_shape)
        self.grid_v = ti.Vector.field(d, self.real, grid.node_shape)
        self.origin, self.gravity = ti.Vector.field(d, self.real, ()), ti.Vector.field(d, self.real, ())
        self.origin[None] = grid.origin.tolist()
        self.gravity[None] = scene.gravity.tolist()
        self.load(particles)

    def load(self, particles):
        """Copy a particle state into the fields."""
        for name in ("x", "v", "C", "J", "mass", "vol0"):
            getattr(self, name).from_numpy(np.ascontiguousarray(getattr(particles, name), dtype=self.np_real))

    def state(self):
        """The particle fields ``x, v, C, J`` as NumPy arrays (waits for running kernels)."""
        return {name: getattr(self, name).to_numpy() for name in ("x", "v", "C", "J")}

    def step(self):
        """Launch one MPM step: clear the grid, P2G, grid update, G2P."""
        self._clear()
        self._p2g()
        self._grid_update()
        self._g2p()

    def run(self, steps):
        """Advance ``steps`` steps and wait until they are done."""
        for _ in range(steps):
            self.step()
        ti.sync()

    # ------------------------------------------------------------------------------ Taichi code
    @ti.func
    def _stencil(self, xp):
        """Base node, offset ``fx = xi - base`` and per-axis weights (rows: the 3 nodes) of a particle."""
        xi = (xp - self.origin[None]) / self.dx
        base = ti.cast(ti.floor(xi - 0.5), ti.i32)
        fx = xi - ti.cast(base, self.real)
        w = ti.Matrix.rows([0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2])
        return base, fx, w

    @ti.func
    def _weight(self, w, offset: ti.template()):
        weight = ti.cast(1.0, self.real)
        for a in ti.static(range(self.dim)):
            weight *= w[offset[a], a]
        return weight

    @ti.kernel
    def _clear(self):
        for node in ti.grouped(self.grid_m):
            self.grid_m[node] = 0.0
            self.grid_mv[node] = ti.Vector.zero(self.real, self.dim)

    @ti.kernel
    def _p2g(self):
        for p in self.x:
            base, fx, w = self._stencil(self.x[p])
            J = self.J[p]
            tau = -(self.K * (J ** (-self.gamma) - 1.0)) * J
            eye = ti.Matrix.identity(self.real, self.dim)
            affine = self.mass[p] * self.C[p] - (self.dt * self.vol0[p] * tau / self.inertia) * eye
            momentum = self.mass[p] * self.v[p]
            for offset in ti.static(ti.grouped(ti.ndrange(*((3,) * self.dim)))):
                weight = self._weight(w, offset)
                dpos = (ti.cast(offset, self.real) - fx) * self.dx
                self.grid_mv[base + offset] += weight * (momentum + affine @ dpos)
                self.grid_m[base + offset] += weight * self.mass[p]

    @ti.func
    def _separate(self, vel, axis: ti.template(), sign: ti.template(), friction: ti.template()):
        """Eq. 25 ``separate`` projection at a wall with inward normal ``sign * e_axis``."""
        out = vel
        vn = sign * vel[axis]
        if vn < 0.0:
            vt = vel
            vt[axis] = 0.0
            vt_norm = vt.norm()
            if vt_norm <= -friction * vn:
                out = ti.Vector.zero(self.real, self.dim)
            else:
                out = vt * (1.0 + friction * vn / vt_norm)
        return out

    @ti.kernel
    def _grid_update(self):
        for node in ti.grouped(self.grid_m):
            m = self.grid_m[node]
            vel = ti.Vector.zero(self.real, self.dim)
            if m > 0.0:
                vel = self.grid_mv[node] * (1.0 / m) + self.dt * self.gravity[None]
                for k in ti.static(range(len(self.walls))):
                    axis, sign, friction = ti.static(self.walls[k])
                    in_band = node[axis] < self.width if sign > 0 else node[axis] > self.cells[axis] - self.width
                    if in_band:
                        vel = self._separate(vel, axis, sign, friction)
            self.grid_v[node] = vel

    @ti.kernel
    def _g2p(self):
        for p in self.x:
            base, fx, w = self._stencil(self.x[p])
            vel = ti.Vector.zero(self.real, self.dim)
            B = ti.Matrix.zero(self.real, self.dim, self.dim)
            for offset in ti.static(ti.grouped(ti.ndrange(*((3,) * self.dim)))):
                weight = self._weight(w, offset)
                dpos = (ti.cast(offset, self.real) - fx) * self.dx
                wv = weight * self.grid_v[base + offset]
                vel += wv
                B += wv.outer_product(dpos)
            C = B / self.inertia
            self.J[p] *= 1.0 + self.dt * C.trace()
            self.x[p] += self.dt * vel
            self.v[p] = vel
            self.C[p] = C
