r"""Momentum conservation: a spinning, drifting elastic disk without gravity or walls, for every scheme.

Set-up: a fixed-corotated disk of radius :math:`R` centred on the origin spins at :math:`\omega` and
drifts at a constant velocity, in an open domain large enough that it never reaches the edge. No external
force acts, so the exact linear momentum :math:`P` and angular momentum :math:`L` (about the origin,
affine part included, :mod:`mpmref.observe.diagnostics`) are constant. The step :math:`\Delta t` is fixed from the
CFL number and the initial wave and particle speeds.

Theory and bounds
-----------------
* **Linear momentum**, every scheme: P2G, the grid update without external forces (the internal forces sum
  to zero since :math:`\sum_i \nabla w_{ip} = 0`) and G2P each conserve :math:`P` in exact arithmetic
  (Jiang et al. 2015; FLIP adds grid *increments*, which sum to the grid's momentum change, zero).
* **Angular momentum**, APIC (with either force), MLS-MPM and PolyPIC: conserved in exact arithmetic
  through the whole step, the affine term included (Jiang et al. 2015 §5.3; Fu et al. 2017; Hu et al.
  2018). Both bounds are round-off (:func:`roundoff_bound`).
* **PIC and FLIP(α)** lose angular momentum: G2P keeps only :math:`\sum_i w_{ip} v_i` and drops the
  particle's affine spin :math:`m_p D_p (C_{yx} - C_{xy})` that APIC would keep. For a rigid spin
  :math:`C_p` is the rotation generator, :math:`C_{yx} - C_{xy} = 2\omega`, so each PIC step removes the
  fraction :func:`spin_loss_rate` :math:`\lambda = 2 D M / I` of :math:`L = I\omega`; FLIP(α) blends
  :math:`1-\alpha` of PIC into the particle velocity and loses :math:`(1-\alpha)\lambda` per step. The check
  asserts a measured decay rate of at least half of that prediction (a lower bound on the loss: the physics
  the case shows). FLIP(α = 1) drops no PIC part but has no affine mode either; its angular momentum changes
  (by about 1 % here), which is asserted to exceed round-off.

On a backend that implements a part (:mod:`verification.framework.applicable`)
---------------------------------------------------------------------------------
Each scheme runs if the backend has it (its transfer; and its force where the variant's label names one: APIC with the
classic force, MLS-MPM); the others are not applicable. The claims hold for any material, kernel, force, precision,
dimension and wall that no particle reaches, so the disk may be of any material the backend has (the same density and
rest P-wave speed: the same Δt), its open walls may be walls of the backend's on a domain padded by their band (their
nodes hold no mass: nothing reads them), the kernel and precision may be the backend's, and a code without 2D runs the
disk's 3D slab (:func:`mpmref.backends.fitting.lifted`, a thin cylinder spinning about z: :math:`L_z` is the spin,
and every component of :math:`L` is conserved). Every bound is computed from what ran: :func:`roundoff_bound` from the
kernel's support, the dimension and the machine epsilon of the scene's dtype, :func:`spin_loss_rate` from each
particle's inertia :math:`D_p` (:func:`spin_inertia`; the linear hat has no constant one). With the linear hat the step
is ``linear_cfl``: FLIP with it blows up at the CFL number of the smooth kernels (its cell-crossing instability, the
reference's too). A fluid disk's
spin is not held rigid by shear, so over the run its particles drift outward; the PIC rate check reads the decay rate
until the spin is gone, and a rigid start is what :func:`spin_loss_rate` predicts from.
"""

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mpmref import SceneBuilder, Simulation
from mpmref.observe.diagnostics import angular_momentum
from mpmref.physics.kernels import compute_stencil
from mpmref.physics.materials import FixedCorotated
from mpmref.physics.scheme import resolve
from mpmref.scene import MethodSpec

from .framework.applicable import Allow, Triage, fit
from .framework.case import VerificationCase
from .framework.common import Check
from .framework.executor import Executor
from .framework.page import Checks, Figure, Page, Table, write_page
from .framework.recording import record
from .framework.report import pyplot, save_figure, write_series

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "momentum_drift.png"

@dataclass(frozen=True)
class Variant:
    """One scheme/force combination of the comparison; ``options`` are extra ``method`` keys."""

    key: str
    label: str
    scheme: str
    options: tuple = ()

    @property
    def method(self):
        return dict(self.options)

    @property
    def transfer(self):
        """The resolved :class:`~mpmref.physics.scheme.TransferSpec` (2D, one elastic material)."""
        method = MethodSpec(scheme=self.scheme, force=self.method.get("force", "mls"), kernel="quadratic",
                            flip_alpha=self.method.get("flip_alpha", 0.0))
        return resolve(method, 2, [FixedCorotated(E=1.0, nu=0.3, rho=1.0)])

    @property
    def conserves_angular_momentum(self):
        """Whether particles carry the affine mode that keeps a rigid spin (APIC, PolyPIC, MLS-MPM)."""
        return self.transfer.affine

    @property
    def pic_fraction(self):
        r"""The fraction :math:`1 - \alpha` of the PIC velocity in G2P (1 for PIC, 0 for affine schemes)."""
        spec = self.transfer
        if spec.affine:
            return 0.0
        return 1.0 - spec.flip_alpha if spec.flip else 1.0


    @property
    def names_force(self):
        """Whether the variant is defined by its force (APIC with the classic force, MLS-MPM); the others' claims
        hold for either force, so a backend may run them with its own."""
        return "force" in self.method or self.scheme == "mls"

    def allows(self, allow):
        """``allow`` with the force free where the variant does not name it."""
        return allow if self.names_force else replace(allow, force=True)


#: the compared schemes; ``scheme = "apic"`` with the default MLS force is MLS-MPM, so it is listed once
VARIANTS = (
    Variant("pic", "PIC", "pic"),
    Variant("flip", "FLIP(α=0.95)", "flip", (("flip_alpha", 0.95),)),
    Variant("flip1", "FLIP(α=1)", "flip", (("flip_alpha", 1.0),)),
    Variant("apic_classic", "APIC (classic ∇w force)", "apic", (("force", "classic"),)),
    Variant("mls", "MLS-MPM (APIC, MLS force)", "mls"),
    Variant("polypic", "PolyPIC", "polypic"),
)
VARIANT = {v.key: v for v in VARIANTS}


@dataclass(frozen=True)
class Params:
    cells: int = 48  # across the unit domain [-1/2, 1/2]^2
    ppc: int = 4
    kernel: str = "quadratic"
    radius: float = 0.2
    omega: float = 2.0  # rad/s
    velocity: tuple = (0.1, 0.05)
    E: float = 1e3
    nu: float = 0.3
    rho: float = 1.0
    cfl: float = 0.25
    #: the CFL number with the linear hat (a backend that has no other kernel): at 0.25 FLIP(0.95) and FLIP(1) blow
    #: up in the quick run (steps 113 and 150 on the reference, 2D and 3D slab: the hat's cell-crossing
    #: instability); at 0.1 every scheme runs the whole quick and full run
    linear_cfl: float = 0.1
    steps: int = 1000
    frames: int = 10  # VTK frames per run
    variants: tuple = tuple(v.key for v in VARIANTS)

    @classmethod
    def quick(cls):
        return cls(cells=32, steps=200)

    @classmethod
    def full(cls):
        return cls(cells=64, steps=4000)


# ------------------------------------------------------------------------------------------ theory
def roundoff_bound(steps, n_particles, ppc, support, dim, eps=np.finfo(np.float64).eps):
    r"""Worst-case relative drift of a sum that one MPM step conserves in exact arithmetic.

    .. math::

        \frac{|Q_n - Q_0|}{S} \le (k\,n + N)\,u, \qquad k = 4\,\mathrm{ppc}\,s^d, \qquad u = \varepsilon/2,

    A computed sum or inner product of :math:`k` terms errs by at most
    :math:`\gamma_k \sum|\text{terms}|`, :math:`\gamma_k = k u/(1 - k u) \approx k u` (Higham, *Accuracy
    and Stability of Numerical Algorithms*, 2nd ed. 2002, §3.1 and §4.2). In one step the longest chain
    per particle is a node sum over the :math:`\mathrm{ppc}\, s^d` particles in a node's support (mass,
    momentum, force), the grid division and update, and the :math:`s^d`-node G2P sums; :math:`k` counts it
    generously as four node sums. Errors add at most linearly over :math:`n` steps, and measuring
    :math:`Q` sums :math:`N` particle terms once more. :math:`S` is the sum of the terms' magnitudes
    (:math:`\sum_p m_p |v_p|` for :math:`P`; :math:`\sum_p m_p (|x_p| |v_p| + D |C_p|)` for :math:`L`).

    Docs: docs/verification.md#momentum-a-spinning-drifting-disk

    Parameters
    ----------
    steps : int                  :math:`n`, steps taken
    n_particles : int            :math:`N`
    ppc : int                    particles per cell
    support : int                kernel support :math:`s` in cells (3 quadratic, 4 cubic)
    dim : int                    :math:`d`
    eps : float                  machine epsilon :math:`\varepsilon` of the arithmetic
    """
    return (4 * ppc * support**dim * steps + n_particles) * eps / 2


def spin_loss_rate(mass, x, center, inertia):
    r"""Fraction of a rigid spin's angular momentum one PIC G2P drops: :math:`\lambda = 2 \sum_p m_p D_p / I`.

    PIC's G2P keeps :math:`v_p = \sum_i w_{ip} v_i` and discards the affine part APIC keeps; for a rigid
    spin that part carries :math:`m_p D_p (C_{yx} - C_{xy}) = 2\omega\, m_p D_p` per particle (Jiang et al.
    2015 §5.3, the angular momentum of the affine term), out of :math:`L = I\omega`,
    :math:`I = \sum_p m_p |x_p - x_c|^2`; for the quadratic and cubic B-splines :math:`D_p = D` and
    :math:`\lambda = 2DM/I`, :math:`M = \sum_p m_p`.

    Docs: docs/verification.md#momentum-a-spinning-drifting-disk

    Parameters
    ----------
    mass : (n,) array;  x : (n, 2) array, in the plane of the spin;  center : (2,) spin centre
    inertia : float or (n,) array   :math:`D_p`: the kernel's :math:`D = k\,\Delta x^2` (:math:`k = 1/4` quadratic,
                                    :math:`1/3` cubic), or each particle's in-plane inertia (:func:`spin_inertia`)
    """
    moment = float(np.sum(mass * np.sum((x - center) ** 2, axis=1)))
    return 2.0 * float(np.sum(mass * inertia)) / moment


def spin_inertia(scene, x):
    r"""Each particle's inertia about the spin axis, :math:`\tfrac12 (D_{p,xx} + D_{p,yy})` of
    :math:`D_p = \sum_i w_{ip} (x_i - x_p)(x_i - x_p)^T` (Jiang et al. 2015 §5.3): :math:`k\,\Delta x^2` for the
    quadratic and cubic B-splines, and for the linear hat a function of where the particle sits in its cell
    (:math:`f_a (1 - f_a)\,\Delta x^2` per axis, with :math:`f_a` its fractional position), which no constant
    gives."""
    stencil = compute_stencil(scene.kernel, x, scene.grid.origin, scene.grid.dx)
    w, r = stencil.node_weights(), stencil.node_offset_vectors()
    return 0.5 * np.einsum("kn,kn->n", w, r[..., 0] ** 2 + r[..., 1] ** 2)


def decay_rate(L_rel, floor=1e-2):
    r"""Mean loss rate per step :math:`-\ln(L_k/L_0)/k`, up to the first step where :math:`L/L_0 <` ``floor``.

    Stopping there keeps the rate out of the noise once the spin is gone.
    """
    below = np.nonzero(L_rel[1:] < floor)[0]
    k = int(below[0]) + 1 if below.size else len(L_rel) - 1
    return float(-np.log(L_rel[k]) / k)


# ------------------------------------------------------------------------------------------- runs
#: what the claims let a backend that implements a part change (module docstring); a variant that does not name its
#: force lets it change too (:meth:`Variant.allows`)
ALLOWS = Allow(materials="any", walls="open", kernel=True, dtype=True, dims=True)


def _scene(params, variant):
    return (SceneBuilder(dim=2, name=f"momentum_{variant.key}")
            .grid(size=1.0, cells=params.cells, origin=[-0.5, -0.5])
            .method(variant.scheme, kernel=params.kernel, **variant.method)
            .material("disk", "fixed_corotated", E=params.E, nu=params.nu, rho=params.rho)
            .ball("disk", center=[0.0, 0.0], radius=params.radius, ppc=params.ppc, angular_velocity=params.omega,
                  velocity=list(params.velocity))
            .walls("open").time(dt=1.0, steps=params.steps).build())  # Δt: time_step()


def time_step(params, scene):
    r""":math:`\Delta t = C\,\Delta x / (c + \omega R + |v|)` with the material's wave speed :math:`c` (``cfl``, or
    ``linear_cfl`` with the linear hat)."""
    speed = scene.max_wave_speed() + params.omega * params.radius + float(np.linalg.norm(params.velocity))
    cfl = params.linear_cfl if scene.method.kernel == "linear" else params.cfl
    return cfl * scene.grid.dx / speed


def _measure(sim, inertia):
    """Time, the scales S_P and S_L, P and L (about the origin, affine part included; L a scalar in 2D, its three
    components in 3D) as one row."""
    m, x, v = sim.mass, sim.x, sim.v
    speed = np.linalg.norm(v, axis=1)
    affine = 0.0 if sim.C is None else inertia * np.sum(m * _skew_magnitude(sim.C))
    P = m @ v
    return (sim.time, float(m @ speed), float(m @ (np.linalg.norm(x, axis=1) * speed)) + affine, *P,
            *np.atleast_1d(angular_momentum(sim.particles, inertia)))


def _skew_magnitude(C):
    r""":math:`\sum_{i<j} |C_{ij}| + |C_{ji}|` per particle: the off-diagonal entries that carry the affine spin."""
    i, j = np.triu_indices(C.shape[1], 1)
    return np.sum(np.abs(C[:, i, j]) + np.abs(C[:, j, i]), axis=1)


def run_variant(job):
    """Run one variant ``job = (params, key, backend)``: momenta every step, VTK frames, timings."""
    params, key, backend = job
    scene = fit(_scene(params, VARIANT[key]), backend, VARIANT[key].allows(ALLOWS)).scene
    sim = Simulation(scene, backend=backend)
    inertia = (scene.kernel.inertia_factor or 0.0) * scene.grid.dx**2  # D of the affine schemes (C: none without)
    dt = time_step(params, scene)
    run = record(sim, lambda s: _measure(s, inertia), params.frames, steps=params.steps, dt=dt)
    a, dim, frames = np.array(run.rows), scene.dim, run.frames
    x0 = frames[0][1]
    rate = spin_loss_rate(sim.mass, x0[:, :2], np.zeros(2), spin_inertia(scene, x0))  # the spin is about z
    return {"t": a[:, 0], "P": a[:, 3:3 + dim], "L": a[:, 3 + dim:], "scale_P": float(a[:, 1].max()),
            "scale_L": float(a[:, 2].max()), "dt": dt, "n_particles": sim.n_particles, "spin_loss_rate": rate,
            "support": scene.kernel.support, "dim": dim, "ppc": round(params.ppc ** (dim / 2)),
            "eps": float(np.finfo(scene.dtype).eps), "wall_s": run.wall_s, "frames": frames}


def run(params=Params(), backend="numpy", executor=None):
    """Run every variant of ``params.variants`` that the backend implements (through ``executor``; default: in this
    process); the others are listed, their checks with them, as not applicable."""
    executor = executor or Executor(workers=1)
    triage = Triage(backend)
    keys = [key for key in params.variants if triage.scene(_variant_label(key), _scene(params, VARIANT[key]),
                                                           VARIANT[key].allows(ALLOWS), run=VARIANT[key].label)]
    if not keys:
        raise triage.nothing_ran()
    runs = executor.map(run_variant, [(params, key, backend) for key in keys])
    return {"params": params, "backend": backend, "runs": dict(zip(keys, runs)), **triage.record()}


def _variant_label(key):
    """The name of a variant's run and of the checks it carries, for the not-applicable list."""
    v = VARIANT[key]
    return f"{v.label}: {LINEAR_CHECK} and {_angular_name(v)}"


# ----------------------------------------------------------------------------------------- figures
def drifts(r):
    """Relative linear and angular momentum drift against time: :math:`|P-P_0|/S_P`, :math:`|L-L_0|/S_L`."""
    return (np.linalg.norm(r["P"] - r["P"][0], axis=1) / r["scale_P"],
            np.linalg.norm(r["L"] - r["L"][0], axis=1) / r["scale_L"])


def spin(r):
    """The angular momentum about the spin axis against time: :math:`L` in 2D, :math:`L_z` in 3D (the slab of
    :func:`mpmref.backends.fitting.lifted` spins about z)."""
    return r["L"][:, -1]


def bound_curve(params, r):
    """:func:`roundoff_bound` after each step of run ``r`` (in the machine epsilon of its dtype and dimension)."""
    return roundoff_bound(np.arange(len(r["t"])), r["n_particles"], r.get("ppc", params.ppc), r["support"],
                          r.get("dim", 2), r.get("eps", np.finfo(np.float64).eps))


LINEAR_CHECK = "linear momentum drift ‖P-P0‖ / Σ m‖v‖"


def _angular_name(v):
    """The name of variant ``v``'s angular momentum check."""
    name = f"{v.label}: angular momentum"
    if v.conserves_angular_momentum:
        return f"{name} drift ‖L-L0‖ / Σ m(‖x‖‖v‖ + D‖C‖)"
    if v.pic_fraction > 0:
        return f"{name} loss per step"
    return f"{name} change ‖L-L0‖ / Σ m(‖x‖‖v‖ + D‖C‖)"


def _angular_check(v, r, drift, bound):
    """Round-off for the affine schemes; the predicted loss for PIC and FLIP(α < 1); a change for FLIP(1)."""
    name = _angular_name(v)
    if v.conserves_angular_momentum:
        return Check(name, drift, "<=", bound, "conserved exactly with the affine term; round-off (k n + N) u")
    if v.pic_fraction > 0:
        predicted = v.pic_fraction * r["spin_loss_rate"]
        return Check(name, decay_rate(spin(r) / spin(r)[0]), ">=", 0.5 * predicted,
                     f"half the predicted (1-α)·2DM/I = {predicted:.3g} per step")
    return Check(name, drift, ">", bound, "no affine mode carries the spin: not conserved (exceeds round-off)")


def checks(result):
    """Linear momentum for all; angular momentum to round-off, or its loss for PIC and FLIP (module docstring)."""
    out = []
    for key, r in result["runs"].items():
        v, (dp, dl) = VARIANT[key], drifts(r)
        bound = float(bound_curve(result["params"], r)[-1])
        out.append(Check(f"{v.label}: {LINEAR_CHECK}", float(dp.max()), "<=", bound,
                         "conserved exactly by every transfer; round-off (k n + N) u"))
        out.append(_angular_check(v, r, float(dl.max()), bound))
    return out


def table(result):
    """The page's table: per scheme, its run, its largest drifts and its measured and predicted spin loss."""
    header = ("scheme", "steps", "particles", "Δt", "max linear drift", "max angular drift", "L_end/L_0",
              "loss per step (measured)", "loss per step (predicted)", "wall time [s]")
    rows = []
    for key, r in result["runs"].items():
        v, (dp, dl) = VARIANT[key], drifts(r)
        measured = decay_rate(spin(r) / spin(r)[0]) if not v.conserves_angular_momentum else 0.0
        rows.append((v.label, len(r["t"]) - 1, r["n_particles"], f"{r['dt']:.3g}", f"{dp.max():.2e}",
                     f"{dl.max():.2e}", f"{spin(r)[-1] / spin(r)[0]:.6f}", f"{measured:.3g}",
                     f"{v.pic_fraction * r['spin_loss_rate']:.3g}", f"{r['wall_s']:.2f}"))
    return Table(header, tuple(rows))


def plot_drifts(result, path):
    """Two log panels: linear and angular momentum drift against time per scheme, with the round-off bound."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharex=True)
    floor = np.finfo(np.float64).eps / 8  # exact zeros are drawn at this floor
    for key, r in result["runs"].items():
        for ax, drift in zip(axes, drifts(r)):
            ax.semilogy(r["t"], np.maximum(drift, floor), label=VARIANT[key].label)
    first = next(iter(result["runs"].values()))
    for ax, what in zip(axes, ("|P - P0| / Σ m|v|", "|L - L0| / Σ m(|x||v| + D|C|)")):
        ax.semilogy(first["t"], bound_curve(result["params"], first), "k--", label="round-off bound (k n + N) u")
        ax.set(xlabel="time [s]", ylabel=what)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_title("linear momentum drift")
    axes[1].set_title("angular momentum drift")
    axes[1].legend(fontsize=8)
    return save_figure(fig, path, caption="Momentum drift per scheme against the round-off bound (dashed). Linear "
                       "momentum stays at round-off for every scheme; angular momentum stays there only for APIC, "
                       "MLS-MPM and PolyPIC, while PIC and FLIP(α) climb far above the bound.")


def plot_angular_momentum(result, path):
    """L(t)/L0 per scheme, with the predicted exponential decay for PIC and FLIP(α)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key, r in result["runs"].items():
        v = VARIANT[key]
        line, = ax.plot(r["t"], spin(r) / spin(r)[0], label=v.label)
        if v.pic_fraction > 0:
            n = np.arange(len(r["t"]))
            ax.plot(r["t"], np.exp(-v.pic_fraction * r["spin_loss_rate"] * n), ":", color=line.get_color(),
                    label=f"{v.label}: exp(-(1-α) 2DM/I n)")
    ax.set(xlabel="time [s]", ylabel="L / L0", title="angular momentum of the spinning disk")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path, caption="L(t)/L0 of the spinning disk. The affine schemes stay at 1; PIC and "
                       "FLIP(α) decay and should follow their dotted predicted exponentials exp(-(1-α) 2DM/I n).")


def report(result, out_dir):
    """Write the drift plots, each variant's VTK series (``vtk/KEY/particles.pvd``) and ``momentum.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [plot_drifts(result, out / "momentum_drift.png"),
             plot_angular_momentum(result, out / "angular_momentum.png")]
    paths += [write_series(out / "vtk" / key, r["frames"]) for key, r in result["runs"].items()]
    page = Page("Momentum of a spinning elastic disk", [
        table(result), Checks(checks(result)), Figure("momentum_drift.png", "drift"),
        Figure("angular_momentum.png", "angular momentum")])
    return paths + [write_page(page, out / "momentum.md")]


#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, main_figure=MAIN_FIGURE)
