r"""The backend against the NumPy reference on the user's scene: the same particles, step by step.

The scene as declared (synchronously), on the reference and on the backend, from the same initial particles, each step
of the Δt the reference takes (the scene's fixed step, or its CFL step of the reference's state), for the budget's
steps. After every step, for each material and each particle array the scene evolves, the difference
:math:`\max|a - r| / S` relative to the array's scale :math:`S` (:func:`differences`): the largest :math:`|x|` for the
positions; the scene's largest speed :math:`|v|_{max}` for the velocities; :math:`|v|_{max}/\Delta x` for the affine
matrices (the velocity gradient a grid of cell :math:`\Delta x` carries at that speed: an error :math:`\delta` in
:math:`C_p` is an error :math:`\delta |v|_{max}` in velocity a cell away, and a field that is uniform, :math:`C_p`
zero but for round-off, is not judged against its own round-off); the largest entry for :math:`F`, :math:`J` and
:math:`J_P`; PolyPIC's modes by the velocity they put on the stencil (:func:`verification.backends.mode_difference`).
With ``--backend numpy`` the candidate is the Numba backend, as in the ``backends`` case.

Bounds (:mod:`verification.backends`): one step within the conformance tolerance of the scene's dtype (:math:`10^{-12}`
in float64, :data:`mpmref.conformance.cases.DEFAULT_RTOL` in float32: the same equations in another order of
operations), and a trajectory of :math:`n` steps within :math:`n` times it (a stable step with non-expansive transfers
and return maps adds the one-step differences without amplifying them). A failure names the particle array and the
material that differ most; ``mpmref conformance check --backend B --scene SCENE.toml`` then finds the stage.
"""

import numpy as np

from mpmref import Simulation
from mpmref.conformance import relative_error
from mpmref.conformance.cases import DEFAULT_RTOL
from mpmref.observe.diagnostics import polypic_mode_norms
from mpmref.scene.sampling import sample_particles

from ..backends import COMPARED_FIELDS, mode_difference, worst
from ..framework.case import VerificationCase
from ..framework.common import Check
from . import Params, as_run, figure_with, load, what_ran, write_report
from .momentum import step_text

#: the candidate when the backend under test is the reference itself
CANDIDATE = "numba"


def candidate_of(backend):
    return CANDIDATE if backend == "numpy" else backend


def differences(ref, cand):
    """The difference of each particle array, per material, relative to its scale (module docstring):
    ``{material: {field: error}}``."""
    p, q = ref.particles, cand.particles
    speed = float(np.max(np.linalg.norm(p.v.astype(float), axis=1), initial=0.0))
    scales = {"v": speed, "C": speed / ref.scene.grid.dx}
    norms = polypic_mode_norms(p, ref.scene.kernel, ref.scene.grid) if p.modes is not None else None
    out = {}
    for mat_id, name in enumerate(ref.scene.materials):
        sel = p.material == mat_id
        out[name] = {f: relative_error(getattr(q, f)[sel], getattr(p, f)[sel], scales.get(f))
                     for f in COMPARED_FIELDS if getattr(p, f) is not None}
        if norms is not None:
            out[name]["modes"] = mode_difference(q.modes[sel], p.modes[sel], norms[sel], p.v)
    return out


def run(params, backend="numpy", executor=None):
    """Step the scene on the reference and the candidate: the differences after every step (``executor`` is not
    used: one pair of runs)."""
    scene = as_run(load(params))
    steps = params.steps(sample_particles(scene).n)
    candidate = candidate_of(backend)
    ref = Simulation(scene, backend="numpy")
    cand = Simulation(scene, backend=candidate, particles=ref.particles.copy())
    history = []
    for _ in range(steps):
        dt = ref.stepper.time_step(ref.particles)
        ref.step(dt)
        cand.step(dt)
        history.append(differences(ref, cand))
    return {"params": params, "backend": backend, "candidate": candidate, "scene": scene.name, "history": history,
            "rtol": DEFAULT_RTOL[scene.dtype.name], "dtype": scene.dtype.name,
            "ran": what_ran(load(params), steps, step_text(scene))}


def backends_run(result, backend):
    """The reference and the candidate."""
    return ("numpy", result["candidate"])


def checks(result):
    """One step within the conformance tolerance, the trajectory within n times it (module docstring)."""
    rtol, history, name = result["rtol"], result["history"], f"{result['scene']} on {result['candidate']}"
    one, where = worst(history[0])
    traj, where_traj = max(worst(h) for h in history)
    n = len(history)
    return [Check(f"{name}: one step, max relative difference ({where})", one, "<=", rtol,
                  f"same equations, different operation order: round-off ({result['dtype']} conformance bound)"),
            Check(f"{name}: {n}-step trajectory, max relative difference ({where_traj})", traj, "<=", n * rtol,
                  "stable step, non-expansive transfers and return maps: n times the one-step bound")]


def plot(result, path):
    """The largest relative difference against the step, with the bound."""
    growth = [worst(h)[0] for h in result["history"]]
    n = np.arange(1, len(growth) + 1)
    floor = np.finfo(result["dtype"]).eps / 8  # exact agreement is drawn at this floor

    def draw(ax):
        ax.semilogy(n, np.maximum(growth, floor), label=f"numpy vs {result['candidate']}")
        ax.semilogy(n, n * result["rtol"], "k--", label=f"bound n·{result['rtol']:g}")

    return figure_with(draw, path, (
        f"{result['scene']}: the largest relative difference between the NumPy reference and {result['candidate']} "
        "(over materials and particle arrays) after each step, from the same particles. Look for the curve under the "
        "dashed bound, growing at most linearly; exact agreement is drawn at the floor eps/8."),
        xlabel="step", ylabel="max relative difference", title=f"{result['scene']}: against the reference")


def report(result, out_dir):
    """Write the growth plot and ``reference.md``."""
    return write_report(out_dir, "reference", f"{result['scene']}: numpy against {result['candidate']}", result,
                        checks(result), plot)


#: this check, for ``mpmref verify --scene``
CASE = VerificationCase(__doc__, Params, run, checks, report, backends_run=backends_run)
