r"""Stability of the user's scene at the extremes of the CFL number: bounded below the limit, caught above it.

The scene as declared (synchronously) runs three times on the backend from the last state kept along its own run
(:func:`verification.scene.trajectory`: where it has done most of what it does), each time step set anew:

* **at CFL 0.3** (the engine's rule :math:`\Delta t = C\Delta x/(c + |v|)`), for the budget's steps. Symplectic Euler
  with lumped masses is stable up to the linear limit :math:`C_{crit}` of the kernel (:func:`linear_limit`:
  :math:`\sqrt 3` for the quadratic B-spline with exact quadrature, 1 for one particle per cell), and 0.3 leaves a
  factor above three for what the linear analysis leaves out (:mod:`verification.extremes`, whose check this is).
  Checked: no velocity changes by more than a cell per step, :math:`|\Delta v|\Delta t/\Delta x \le 1` (the engine's
  boundedness criterion, :func:`mpmref.run.stability.first_unbounded`), nothing turns non-finite, and the kinetic and
  stored energy :math:`K + \Psi` stay within :data:`ENERGY_FACTOR` times what the scene has to give,
  :math:`E_{avail} = K_0 + \Psi_0 + M‖g‖H` (:math:`H` the domain's extent along gravity: walls, transfers and
  plasticity only take energy away). Where energy enters the scene (emitters, moving colliders, scripted or dynamic
  rigid bodies) no such bound holds and the energy check is not applicable.
* **at the scheme's measured limit** (:func:`mpmref.run.stability.stable_cfl`: the smallest over the conditions of
  ``docs/stability.md``): measured on one probe, so a finding, not a check: how many steps the scene stayed bounded.
* **above the linear limit**: a fixed :math:`\Delta t = 2 C_{crit}\,\Delta x / c` (:math:`c` the fastest wave speed at
  rest), twice the largest limit of any quadrature (exact quadrature has the smallest top eigenvalue). The top mode
  then grows by :math:`|\lambda|` per step (:func:`growth_per_step`; 13.9 at twice the limit), from round-off
  :math:`u` to order one in :math:`n^* = \ln(1/u)/\ln|\lambda|` steps. Checked: the run is caught (the engine's
  :class:`~mpmref.errors.InstabilityError`, a non-finite value, a velocity change of more than a cell per step, or the
  energy past its bound) within :math:`\max(n, 4 n^*)` steps. The analysis is that of an elastic response, so for a
  scene with a plastic material (whose return map caps the stress) this is a finding; for a scene where nothing moves
  and nothing is stressed (no mode is excited) it is not applicable.
"""

import math
import warnings

import numpy as np
from scipy.special import zeta

from mpmref.backends.capabilities import material_type
from mpmref.errors import DomainExitError, MpmrefError
from mpmref.run.stability import StabilityWarning, first_unbounded, stable_cfl

from ..framework.applicable import HYPERELASTIC, NotApplicable
from ..framework.case import VerificationCase
from ..framework.common import Check, Finding
from ..framework.page import Table
from . import Params, as_run, figure_with, matched, resume, trajectory, what_ran, write_report

SMALL_CFL = 0.3
#: the fixed step above the limit, in units of the kernel's linear limit with exact quadrature
ABOVE = 2.0
#: how far K + Ψ may exceed what the scene has to give before a run counts as unbounded (as in the extremes case)
ENERGY_FACTOR = 10.0
#: how many times n* the run above the limit lasts at least
CATCH_MARGIN = 4


# ------------------------------------------------------------------------------------------------------ theory
def linear_limit(degree):
    r"""The CFL number :math:`C_{crit} = 2/\sqrt{s}` above which symplectic Euler with lumped masses and a B-spline of
    ``degree`` :math:`p` (exact quadrature) is unstable.

    :math:`s` is the top of the 1D Fourier symbol of :math:`M^{-1}K` in units of :math:`c^2/\Delta x^2`, at
    :math:`\theta = \pi`: the stiffness symbol :math:`\sum_m (\theta + 2\pi m)^2\,\mathrm{sinc}^{2p+2}((\theta +
    2\pi m)/2)` over the lumped mass 1,

    .. math:: s = 8\,(2/\pi)^{2p}\,(1 - 2^{-2p})\,\zeta(2p),

    which is :math:`4/3` for the quadratic B-spline (:math:`C_{crit} = \sqrt 3`, :mod:`verification.extremes`), 4
    for the linear one (1) and :math:`8/15` for the cubic one (2.74); in 2D and 3D the tensor-product symbol peaks on
    the axes at the same value.
    """
    s = 8.0 * (2.0 / math.pi) ** (2 * degree) * (1.0 - 2.0 ** (-2 * degree)) * float(zeta(2 * degree))
    return 2.0 / math.sqrt(s)


def growth_per_step(ratio):
    r""":math:`|\lambda|` of the top mode when the step is ``ratio`` times the linear limit: symplectic Euler on
    :math:`\ddot x = -\omega^2 x` has :math:`\lambda^2 - (2 - h^2\omega^2)\lambda + 1 = 0`, and :math:`h\omega = 2\,`
    ``ratio``."""
    b = 2.0 - (2.0 * ratio) ** 2
    return 1.0 if b * b <= 4.0 else (abs(b) + math.sqrt(b * b - 4.0)) / 2.0


def steps_to_catch(eps, growth):
    r""":math:`n^* = \ln(1/u)/\ln|\lambda|`, :math:`u = \varepsilon/2`: the steps from round-off to order one."""
    return math.log(2.0 / eps) / math.log(growth)


# -------------------------------------------------------------------------------------------------------- runs
def available_energy(scene, sim):
    r""":math:`E_{avail} = K_0 + \Psi_0 + M‖g‖H` (module docstring), or ``None`` where energy enters the scene."""
    moving = any(np.any(c.velocity != 0.0) for c in scene.colliders)
    driven = any(body.motion != "fixed" for body in scene.rigid_bodies)
    if scene.emitters or moving or driven:
        return None
    d = sim.diagnostics()
    g = np.asarray(scene.gravity, dtype=float)
    extent = np.array(scene.grid.cells) * scene.grid.dx
    height = float(np.abs(g) @ extent)  # |g| H: the domain's extent along g, times |g|
    return d["kinetic"] + d["kinetic_affine"] + d["kinetic_modes"] + d["elastic"] + float(sim.mass.sum()) * height


def stored(sim):
    d = sim.diagnostics()
    return d["kinetic"] + d["kinetic_affine"] + d["kinetic_modes"] + d["elastic"]


def probe(scene, backend, steps, state):
    r"""Run ``scene`` for ``steps`` steps on ``backend`` from ``state``: the largest velocity change per step in cells
    (``jump``), the largest :math:`(K + \Psi)/E_{avail}` (``energy``; ``nan`` without a bound), how many steps ran, and
    the step at which the run was caught and how (``caught``, ``how``: ``None`` if never). A particle leaving the
    domain at a bounded step ends the run (``left``): the scene's own motion, not an instability. The velocity changes
    are those of the particles present before and after each step, matched by id (:func:`~verification.scene.matched`:
    an emitter's release joins, the domain's edge deletes)."""
    sim = resume(scene, backend, state)
    scale = available_energy(scene, sim)
    out = {"jump": 0.0, "energy": math.nan if scale is None else stored(sim) / scale, "caught": None, "how": None,
           "steps": steps, "left": None}
    for n in range(1, steps + 1):
        ids, v = sim.id.copy(), sim.v.copy()
        try:
            with warnings.catch_warnings(), np.errstate(all="ignore"):  # past the limit on purpose: no warnings
                warnings.simplefilter("ignore", StabilityWarning)
                dt = sim.step()
                energy = stored(sim) / scale if scale is not None else math.nan
            energy = energy if math.isfinite(energy) or scale is None else math.inf
        except DomainExitError as exc:
            return {**out, "steps": n - 1, "left": str(exc)}
        except MpmrefError as exc:  # the engine's InstabilityError, NonFiniteError, every particle gone
            return {**out, "jump": math.inf, "caught": n, "how": type(exc).__name__, "steps": n}
        before, after = matched(ids, sim.id)
        v, v_new = v[before], sim.v[after]
        change = np.linalg.norm(v_new.astype(float) - v, axis=1)
        cells = float(np.max(change, initial=0.0)) * dt / scene.grid.dx
        out["jump"] = max(out["jump"], cells if math.isfinite(cells) else math.inf)
        out["energy"] = max(out["energy"], energy)
        if first_unbounded(v, v_new, dt, scene.grid.dx) is not None or not math.isfinite(cells):
            return {**out, "caught": n, "how": "a velocity change of more than a cell in one step", "steps": n}
        if out["energy"] > ENERGY_FACTOR:
            return {**out, "caught": n, "how": f"K + Ψ above {ENERGY_FACTOR:g} times the energy available", "steps": n}
    return out


def excited(scene, sim):
    """Whether anything moves or is stressed in the initial state, or gravity acts: what seeds the unstable modes."""
    return bool(np.any(scene.gravity != 0.0) or np.any(sim.v != 0.0) or sim.diagnostics()["elastic"] > 0.0)


def run(params, backend="numpy", executor=None):
    """The three runs of the module docstring on ``backend``, from the last state kept along the scene's run
    (:func:`verification.scene.trajectory`; ``executor`` is not used)."""
    path = trajectory(params, backend)
    scene, state = path.scene, path.states[-1]
    start = resume(scene, backend, state)
    steps = params.steps(start.n_particles)
    degree = scene.kernel.support - 1
    limit, measured = linear_limit(degree), stable_cfl(scene.method.scheme)
    growth = growth_per_step(ABOVE)
    eps = float(np.finfo(scene.dtype).eps)
    above_steps = max(steps, math.ceil(CATCH_MARGIN * steps_to_catch(eps, growth)))
    dt_above = ABOVE * limit * scene.grid.dx / scene.max_wave_speed()
    runs = {"small": probe(as_run(scene, time={"cfl": SMALL_CFL}), backend, steps, state),
            "measured": probe(as_run(scene, time={"cfl": measured}), backend, steps, state),
            "above": probe(as_run(scene, time={"dt": dt_above}), backend, above_steps, state)}
    items = []
    if math.isnan(runs["small"]["energy"]):
        items.append(NotApplicable(f"{scene.name}: K + Ψ at CFL {SMALL_CFL:g} within {ENERGY_FACTOR:g} times the "
                                   "energy available", ("energy enters the scene (emitters, moving colliders, scripted "
                                                        "or dynamic rigid bodies): no bound on it",)))
    if not excited(scene, start):
        items.append(NotApplicable(f"{scene.name}: caught above the linear limit",
                                   ("nothing moves and nothing is stressed, and no gravity acts: no mode is excited",)))
    plastic = [material_type(m) for m in scene.materials.values() if material_type(m) not in HYPERELASTIC]
    return {"params": params, "backend": backend, "scene": scene.name, "runs": runs, "steps": steps,
            "above_steps": above_steps, "limit": limit, "measured": measured, "growth": growth,
            "n_star": steps_to_catch(eps, growth), "dt_above": dt_above, "scheme": scene.method.scheme,
            "kernel": scene.method.kernel, "judged": not plastic and excited(scene, start), "plastic": plastic,
            "not_applicable": items, "ran": what_ran(scene, steps, "Δt set by each run", (state.step, path.own))}


# ------------------------------------------------------------------------------------------------------ checks
def checks(result):
    """Bounded at CFL 0.3 (velocity changes, energy where bounded); caught above the linear limit (module docstring,
    where it is judged)."""
    name, small, above = result["scene"], result["runs"]["small"], result["runs"]["above"]
    out = [Check(f"{name}: at CFL {SMALL_CFL:g}, largest velocity change per step ‖Δv‖Δt/Δx", small["jump"], "<=",
                 1.0, f"linear stability up to CFL {result['limit']:.3g} ({result['kernel']} kernel, exact "
                 "quadrature; 1 at one particle per cell): a bounded step changes no velocity by a cell per step")]
    if not math.isnan(small["energy"]):
        out.append(Check(f"{name}: at CFL {SMALL_CFL:g}, largest (K + Ψ) / (K0 + Ψ0 + M‖g‖H)", small["energy"], "<=",
                         ENERGY_FACTOR, "walls, transfers and plasticity only take energy away: the kinetic and "
                         "stored energy never exceed what the scene starts with plus what gravity can give"))
    if result["judged"]:
        caught = above["caught"] if above["caught"] is not None else math.inf
        out.append(Check(f"{name}: at {ABOVE:g} x the linear limit (Δt = {result['dt_above']:.3g}), step at which the "
                         "instability is caught", caught, "<=", result["above_steps"],
                         f"the top mode grows {result['growth']:.3g}x a step: from round-off to order one in "
                         f"{result['n_star']:.1f} steps; caught within {CATCH_MARGIN} times that"))
    return out


def findings(result):
    """The run at the scheme's measured limit, and the run above the limit where it is not judged."""
    name, measured, above = result["scene"], result["runs"]["measured"], result["runs"]["above"]
    out = [Finding(f"{name}: steps bounded at CFL {result['measured']:g}, the smallest measured limit of "
                   f"{result['scheme']}", measured["steps"] if measured["caught"] is None else measured["caught"] - 1,
                   _outcome(measured) + " The limits were measured on one probe (docs/stability.md): not a "
                   "guarantee for this scene, so not judged.")]
    if not result["judged"] and result["plastic"]:
        out.append(Finding(f"{name}: step at which the run above the linear limit was caught",
                           math.inf if above["caught"] is None else above["caught"],
                           _outcome(above) + f" The scene has {', '.join(result['plastic'])}: its return map caps the "
                           "stress, beyond the linear analysis, so not judged."))
    return out


def _outcome(run):
    if run["caught"] is not None:
        return f"Caught at step {run['caught']} ({run['how']})."
    left = f" A particle left the domain at a bounded step ({run['left']})." if run["left"] else ""
    return f"Bounded over {run['steps']} steps (largest ‖Δv‖Δt/Δx {run['jump']:.3g}).{left}"


# ------------------------------------------------------------------------------------------------------ report
LABELS = {"small": "CFL {small:g}", "measured": "CFL {measured:g} (measured limit)",
          "above": "Δt = {dt:.3g} ({above:g} x the linear limit {limit:.3g})"}


def _label(result, key):
    return LABELS[key].format(small=SMALL_CFL, measured=result["measured"], dt=result["dt_above"], above=ABOVE,
                              limit=result["limit"])


def plot(result, path):
    """The largest velocity change per step of each run, against the engine's bound of a cell per step."""
    def draw(ax):
        ax.bar([_label(result, k) for k in result["runs"]],
               [float(np.clip(r["jump"], 1e-12, 1e3)) for r in result["runs"].values()], color=["C2", "C1", "C3"])
        ax.axhline(1.0, color="k", ls="--", lw=1, label="a cell per step (the engine's bound)")
        ax.tick_params(axis="x", labelsize=7)

    return figure_with(draw, path, (
        f"{result['scene']}: the largest velocity change in one step, in cells, of each run (drawn between 1e-12 and "
        "1e3: a run that blew up reaches the top). Look for the run at CFL 0.3 under the dashed line (checked) and "
        "the run above the linear limit over it (caught, checked where the analysis applies)."),
        yscale="log", ylabel="largest ‖Δv‖Δt/Δx", title=f"{result['scene']}: stability at the extremes of CFL")


def report(result, out_dir):
    """Write ``stability.md`` with the three runs, and a figure of their largest velocity changes."""
    rows = tuple((_label(result, k), r["steps"], f"{r['jump']:.3g}", f"{r['energy']:.3g}", _outcome(r))
                 for k, r in result["runs"].items())
    table = Table(("run", "steps", "largest ‖Δv‖Δt/Δx", "largest (K+Ψ)/E_avail", "outcome"), rows)
    return write_report(out_dir, "stability", f"Stability of {result['scene']}", result, checks(result), plot, table)


#: this check, for ``mpmref verify --scene``
CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings)
