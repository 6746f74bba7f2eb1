r"""Backends agree: every scheme × material, one step and a trajectory, on the reference and a candidate.

Set-up: one 2D (or 3D) scene per scheme, kernel and dimension holding five disks (spheres), one of each
material of :data:`mpmref.conformance.cases.MATERIALS` (fixed-corotated, Neo-Hookean, fluid, snow,
sand), spinning and thrown at the floor under gravity; the walls are ``separate`` with friction, so the
trajectory runs walls, contact and both plastic return maps. The same initial particles are stepped
with a fixed :math:`\Delta t` on the NumPy reference and on the candidate backend (``numba``; with
``--backend NAME`` other than ``numpy``, that backend). After every step the case measures, for each
material and each particle array (``x, v, C, F, J, Jp``, those allocated), the relative difference
:math:`\max|a - r| / \max|r|` (:func:`mpmref.conformance.relative_error`). PolyPIC's higher modes are
compared by the velocity they put on the stencil, relative to the particle speed (:func:`mode_difference`):
a mode whose stencil norm :math:`N_r = \sum_i w_{ip} s_r(x_i)^2` is tiny has an ill-conditioned coefficient
(``docs/transfers.md``, conditioning of the top modes) but carries almost no velocity, so its raw
coefficient would measure conditioning, not disagreement.

Theory and bounds
-----------------
* **One step**: the two backends evaluate the same equations and differ only in the order of floating-
  point operations (blocked, coloured P2G sums; fused loops). The per-stage conformance bound applies:
  :math:`\le 10^{-12}` in float64 (the design rule for backends; :mod:`mpmref.conformance`).
* **Trajectory of** :math:`n` **steps**: a difference :math:`\delta_k` made at step :math:`k` is carried by
  the linearised step map; for a stable explicit step its powers are bounded (:math:`\|G^j\| \le K`),
  the transfers are non-expansive in the kinetic energy norm (Jiang et al. 2015 §6) and the plastic return
  maps are projections onto convex sets (non-expansive), so :math:`\delta_n \le K \sum_k \delta_k
  \le K\,n\,\delta_1`. With :math:`K = 1` the bound is :math:`n \cdot 10^{-12}`: linear, not exponential,
  growth. A particle sitting on a branch point (the yield surface, a wall's separation test) to within
  round-off could still switch branches; over these short trajectories none does, which is part of what
  the check verifies.

On a backend that implements a part (:mod:`verification.framework.applicable`): each scheme runs if the backend has it,
with the backend's kernel and, where the variant does not name it, its force; a code without 2D runs the 3D slab of the
scene (:func:`mpmref.backends.fitting.lifted`); the others are not applicable. The claim is made material by
material, so a run keeps the disks of the materials the backend has (with the parameters it fixes) and leaves the
others out; the walls may be a static wall it has and lose their friction if it has none. The bounds are the same: the
same equations on both sides.
"""

from dataclasses import dataclass, replace
from pathlib import Path
from time import perf_counter

import numpy as np

from mpmref import SceneBuilder, Simulation
from mpmref.conformance import relative_error
from mpmref.conformance.cases import MATERIALS
from mpmref.observe.diagnostics import polypic_mode_norms
from mpmref.state import EVOLVING_FIELDS

from .framework.applicable import Allow, Triage, fit
from .framework.case import VerificationCase
from .framework.common import Check
from .framework.executor import Executor
from .framework.page import Checks, Figure, Page, Table, Text, write_page
from .framework.report import pyplot, save_figure, snapshot, write_series
from .momentum import VARIANT, VARIANTS

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "difference_growth.png"

#: the particle arrays compared row by row: the evolving ones but the PolyPIC modes (compared by
#: :func:`mode_difference`)
COMPARED_FIELDS = tuple(name for name in EVOLVING_FIELDS if name != "modes")
ONE_STEP_RTOL = 1e-12
#: what the claim lets a backend that implements a part change (module docstring)
ALLOWS = Allow(materials="subset", walls="static", friction=True, kernel=True, dims=True)


def allows(key):
    """:data:`ALLOWS` for variant ``key``, with the force free where the variant does not name it."""
    return VARIANT[key].allows(ALLOWS)


@dataclass(frozen=True)
class Params:
    candidate: str = "numba"  # compared with the reference when --backend is numpy
    dims: tuple = (2,)
    kernels: tuple = ("quadratic", "cubic")
    variants: tuple = tuple(v.key for v in VARIANTS)
    cells: int = 32
    dt: float = 2e-4  # CFL about 0.4 for the stiffest wave speed (snow, about 62 m/s) at 32 cells
    steps: int = 200
    frames: int = 10

    @classmethod
    def quick(cls):
        return cls(kernels=("quadratic",), steps=20)

    @classmethod
    def full(cls):
        return cls(dims=(2, 3), steps=400)


def trajectory_bound(steps):
    r""":math:`n \cdot 10^{-12}`: one-step differences added up without amplification (module docstring)."""
    return steps * ONE_STEP_RTOL


# --------------------------------------------------------------------------------------------- runs
def _scene(params, dim, kernel, variant):
    builder = (SceneBuilder(dim=dim, name=f"backends_{variant.key}").grid(size=1.0, cells=params.cells)
               .method(variant.scheme, kernel=kernel, **variant.method).gravity([0.0, -9.8] + [0.0] * (dim - 2)))
    spin = 5.0 if dim == 2 else [0.0, 0.0, 5.0]
    for i, name in enumerate(MATERIALS):
        builder.material(name, **MATERIALS[name])
        center = [0.15 + 0.175 * i, 0.2] + [0.5] * (dim - 2)
        builder.ball(name, center=center, radius=0.07, ppc=2**dim,
                     velocity=[0.5 - 0.25 * i, -3.0] + [0.0] * (dim - 2), angular_velocity=spin)
    return builder.walls("separate", friction=0.3).time(dt=params.dt, steps=params.steps).build()


def compiled_scenes(params, backend="numpy"):
    """``[(backend, scene)]`` this case runs on a compiled backend (see :mod:`verification.framework.warmup`)."""
    candidate = params.candidate if backend == "numpy" else backend
    triage = Triage(candidate)
    scenes = [triage.fit(key, _scene(params, dim, kernel, VARIANT[key]), allows(key)) for dim in params.dims
              for kernel in params.kernels for key in params.variants if candidate != "numpy"]
    return [(candidate, scene) for scene in scenes if scene is not None]


def mode_difference(candidate, reference, norms, velocity):
    r"""Velocity difference the higher PolyPIC modes put on the stencil, relative to the particle speed.

    .. math:: \frac{\max_p \big(\sum_r N_{pr} |c^{a}_{pr} - c^{r}_{pr}|^2\big)^{1/2}}{\max_p |v^{r}_p|}

    the RMS over the stencil of the modes' velocity difference (the modes are orthogonal under the weights,
    :func:`mpmref.observe.diagnostics.polypic_mode_norms`), against the speed scale of the reference particles.
    """
    diff = np.sqrt(np.max(np.sum(norms * np.sum((candidate - reference) ** 2, axis=2), axis=1), initial=0.0))
    scale = np.max(np.linalg.norm(velocity, axis=1), initial=0.0)
    return float(diff / scale) if scale > 0 else float(diff)


def differences(ref, cand):
    """Relative difference per material and particle array: ``{material: {field: error}}``."""
    p, q = ref.particles, cand.particles
    norms = polypic_mode_norms(p, ref.scene.kernel, ref.scene.grid) if p.modes is not None else None
    out = {}
    for mat_id, name in enumerate(ref.scene.materials):
        sel = p.material == mat_id
        out[name] = {f: relative_error(getattr(q, f)[sel], getattr(p, f)[sel])
                     for f in COMPARED_FIELDS if getattr(p, f) is not None}
        if norms is not None:
            out[name]["modes"] = mode_difference(q.modes[sel], p.modes[sel], norms[sel], p.v[sel])
    return out


def _frame(ref, cand):
    t, x, data = snapshot(cand)
    return t, x, {**data, "velocity_difference": cand.v - ref.v, "position_difference": cand.x - ref.x}


def run_pair(job):
    """Step one scene on the reference and the candidate: differences after every step, wall times."""
    params, dim, kernel, key, candidate = job
    scene = fit(_scene(params, dim, kernel, VARIANT[key]), candidate, allows(key)).scene
    ref = Simulation(scene, backend="numpy")
    cand = Simulation(scene, backend=candidate, particles=ref.particles.copy())
    history, frames, wall = [], [], {"numpy": 0.0, candidate: 0.0}
    every = max(1, params.steps // params.frames)
    for n in range(1, params.steps + 1):
        for name, sim in (("numpy", ref), (candidate, cand)):
            start = perf_counter()
            sim.step(params.dt)
            if n > 1:  # the first step of a compiled backend includes compiling or loading its kernels
                wall[name] += perf_counter() - start
        history.append(differences(ref, cand))
        if n % every == 0 or n == 1:
            frames.append(_frame(ref, cand))
    return {"dim": scene.dim, "kernel": kernel, "key": key, "candidate": candidate, "n_particles": ref.n_particles,
            "history": history, "wall_per_step": {k: w / max(1, params.steps - 1) for k, w in wall.items()},
            "frames": frames}


def run(params=Params(), backend="numpy", executor=None):
    """Compare ``backend`` (or ``params.candidate`` when ``backend`` is the reference) with NumPy."""
    executor = executor or Executor(workers=1)
    candidate = params.candidate if backend == "numpy" else backend
    triage = Triage(candidate)
    jobs = [(params, dim, kernel, key, candidate) for dim in params.dims for kernel in params.kernels
            for key in params.variants
            if triage.scene(f"{_label_of(dim, kernel, key)}: one step and trajectory",
                            _scene(params, dim, kernel, VARIANT[key]), allows(key), run=_label_of(dim, kernel, key))]
    if not jobs:
        raise triage.nothing_ran()
    # the parameters as run: the candidate is the backend compared, also when it is not the default's numba
    return {"params": replace(params, candidate=candidate), "candidate": candidate, "executor": executor.describe(),
            "runs": executor.map(run_pair, jobs), **triage.record()}


def backends_run(result, backend):
    """The reference and the candidate: this case runs both."""
    return ("numpy", result["candidate"])


# ------------------------------------------------------------------------------------------- checks
def worst(step_diffs):
    """Largest difference over materials and arrays at one step, and where it is."""
    return max((err, f"{mat}.{field}") for mat, fields in step_diffs.items() for field, err in fields.items())


def _label(r):
    return _label_of(r["dim"], r["kernel"], r["key"])


def _label_of(dim, kernel, key):
    return f"{dim}D {kernel} {VARIANT[key].label}"


def checks(result):
    """One step within 1e-12; the whole trajectory within n·1e-12 (module docstring)."""
    out = []
    for r in result["runs"]:
        one, where = worst(r["history"][0])
        out.append(Check(f"{_label(r)}: one step, max relative difference ({where})", one, "<=", ONE_STEP_RTOL,
                         "same equations, different operation order: round-off (conformance bound)"))
        traj, where = max(worst(h) for h in r["history"])
        n = len(r["history"])
        out.append(Check(f"{_label(r)}: {n}-step trajectory, max relative difference ({where})", traj, "<=",
                         trajectory_bound(n), "stable step, non-expansive transfers and return maps: n·1e-12"))
    return out


def table(result):
    """The page's table: per run, the largest difference per material after one step and over the trajectory."""
    materials = [m for m in MATERIALS if any(m in r["history"][0] for r in result["runs"])]  # those that ran
    header = ("dim", "kernel", "scheme", *(f"{m}: 1 step / trajectory" for m in materials), "s/step numpy",
              "s/step candidate")
    rows = []
    for r in result["runs"]:
        cells = []
        for m in materials:
            if m not in r["history"][0]:
                cells.append("—")
                continue
            one = max(r["history"][0][m].values())
            traj = max(max(h[m].values()) for h in r["history"])
            cells.append(f"{one:.1e} / {traj:.1e}")
        w = r["wall_per_step"]
        rows.append((r["dim"], r["kernel"], VARIANT[r["key"]].label, *cells, f"{w['numpy']:.2e}",
                     f"{w[r['candidate']]:.2e}"))
    return Table(header, tuple(rows))


# ------------------------------------------------------------------------------------------ figures
def plot_growth(result, path):
    """Max relative difference against the step number per run, with the bound n·1e-12."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    floor = np.finfo(np.float64).eps / 8  # exact agreement is drawn at this floor
    for r in result["runs"]:
        growth = [worst(h)[0] for h in r["history"]]
        ax.semilogy(np.arange(1, len(growth) + 1), np.maximum(growth, floor), label=_label(r))
    n = np.arange(1, result["params"].steps + 1)
    ax.semilogy(n, trajectory_bound(n), "k--", label="bound n·1e-12")
    ax.set(xlabel="step", ylabel="max relative difference", title=f"numpy vs {result['candidate']}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    return save_figure(fig, path, caption=(
        f"Largest relative difference between NumPy and {result['candidate']} (over materials and particle "
        "arrays) against the step number, per run. Look for every curve below the dashed bound n·1e-12 and "
        "growing at most linearly; exact agreement is drawn at the floor eps/8."))


def report(result, out_dir):
    """Write the growth plot, each run's candidate VTK series with the differences, and ``backends.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [plot_growth(result, out / "difference_growth.png")]
    paths += [write_series(out / "vtk" / f"{r['dim']}d_{r['kernel']}_{r['key']}", r["frames"])
              for r in result["runs"]]
    page = Page(f"NumPy reference vs {result['candidate']}", [
        Text("Max relative difference per material (over every particle array) after one step and over the "
             "trajectory; wall time per step after the first (so without compilation), measured while the runs "
             f"shared the machine ({result['executor']}, Numba at its default thread count): a rough figure, not a "
             "benchmark (`mpmref bench` is one)."),
        table(result), Checks(checks(result)), Figure("difference_growth.png", "growth")])
    return paths + [write_page(page, out / "backends.md")]


#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, backends_run=backends_run,
                        compiled_scenes=compiled_scenes, main_figure=MAIN_FIGURE)
