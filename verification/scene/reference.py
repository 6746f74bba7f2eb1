r"""The backend against the NumPy reference on the user's scene: the same particles, step by step, along its run.

The scene as declared (synchronously) is advanced on the backend under test (:func:`verification.scene.trajectory`),
and from each state kept along that run the reference and the backend step the same particles for ``segment`` steps,
each of the Δt the reference takes (the scene's fixed step, or its CFL step of the reference's state). So the
comparison meets what the scene does, a landing or a splash as well as a free fall, and each segment starts from the
state the backend itself reached. After every step, for each material and each particle array the scene evolves, the
difference :math:`\max|a - r| / S` relative to the array's scale :math:`S` (:func:`differences`): the largest
:math:`|x|` for the positions; the step's velocity scale :math:`V = \max(|v|_{max}, |g|\Delta t)` for the velocities
(:func:`speed_scale`: at rest under gravity the velocities are round-off of :math:`g\Delta t`); :math:`V/\Delta x` for
the affine matrices (the velocity gradient a grid of cell :math:`\Delta x` carries at that speed: an error
:math:`\delta` in :math:`C_p` is an error :math:`\delta |v|_{max}` in velocity a cell away, and a field that is
uniform, :math:`C_p` zero but for round-off, is not judged against its own round-off); the largest entry for
:math:`F`, :math:`J` and :math:`J_P`; PolyPIC's modes by the velocity they put on the stencil
(:func:`verification.backends.mode_difference`). With ``--backend numpy`` the candidate is the Numba backend (the run
advances on the reference), as in the ``backends`` case.

Bounds (:mod:`verification.backends`): one step within the conformance tolerance of the scene's dtype (:math:`10^{-12}`
in float64, :data:`mpmref.conformance.cases.DEFAULT_RTOL` in float32: the same equations in another order of
operations), and :math:`n` steps within :math:`n` times it (a stable step with non-expansive transfers and return maps
adds the one-step differences without amplifying them). A failure names the particle array and the material that
differ most and the step of the scene's run where the segment started; ``mpmref conformance check --backend B
--scene SCENE.toml`` then finds the stage.
"""

import math
import warnings

import numpy as np

from mpmref.conformance import relative_error
from mpmref.conformance.cases import DEFAULT_RTOL
from mpmref.errors import MpmrefError
from mpmref.observe.diagnostics import polypic_mode_norms
from mpmref.run.stability import StabilityWarning

from ..backends import COMPARED_FIELDS, mode_difference, worst
from ..framework.applicable import NotApplicable
from ..framework.case import VerificationCase
from ..framework.common import Check, Finding
from ..framework.coverage import Tracker
from . import Params, figure_with, matched, resume, trajectory, write_report
from .momentum import step_text

#: the candidate when the backend under test is the reference itself
CANDIDATE = "numba"


def candidate_of(backend):
    return CANDIDATE if backend == "numpy" else backend


def differences(ref, cand, dt=0.0):
    """The difference of each particle array, per material, relative to its scale (module docstring):
    ``{material: {field: error}}``, over the particles matched by id (:func:`~verification.scene.matched`); a particle
    that only one of the two holds (one deleted it at the domain's edge, the other did not) is an infinite difference,
    ``{"particles": {"ids differ": inf}}``. ``dt``: the step just taken (:func:`speed_scale`)."""
    i, j = matched(ref.particles.id, cand.particles.id)
    p, q = ref.particles.select(i), cand.particles.select(j)
    speed = speed_scale(p.v, ref.scene.gravity, dt)
    scales = {"v": speed, "C": speed / ref.scene.grid.dx}
    norms = polypic_mode_norms(p, ref.scene.kernel, ref.scene.grid) if p.modes is not None else None
    out = {}
    for mat_id, name in enumerate(ref.scene.materials):
        sel = p.material == mat_id
        out[name] = {f: relative_error(getattr(q, f)[sel], getattr(p, f)[sel], scales.get(f))
                     for f in COMPARED_FIELDS if getattr(p, f) is not None}
        if norms is not None:
            out[name]["modes"] = mode_difference(q.modes[sel], p.modes[sel], norms[sel], p.v)
    if i.size < max(ref.n_particles, cand.n_particles):
        out["particles"] = {"ids differ": math.inf}
    return out


def speed_scale(v, gravity, dt):
    r"""The velocity scale of a step: :math:`\max(\max_p |v_p|,\; |g|\,\Delta t)`.

    A body at rest under gravity has :math:`v_p` at round-off: each step adds :math:`g\Delta t` and the stress that
    holds the body takes it back, so its velocities are differences of terms of size :math:`|g|\Delta t`, and their
    round-off is relative to that, not to the velocities themselves (against which two correct codes at rest differ
    by order one: measured, a jelly settled on its floor, :math:`C` differing by 1.2 of :math:`\max|v|/\Delta x`)."""
    largest = float(np.max(np.linalg.norm(v.astype(float), axis=1), initial=0.0))
    return max(largest, float(np.linalg.norm(gravity)) * dt)


def run(params, backend="numpy", executor=None):
    """From each kept state of the scene's run, the reference and the candidate for ``segment`` steps: the differences
    after every step (``executor`` is not used)."""
    path = trajectory(params, backend)
    candidate = candidate_of(backend)
    tracker = Tracker(path.scene)
    segments = [compare_from(path.scene, candidate, state, params.segment, tracker) for state in path.states]
    void = [NotApplicable(f"{path.scene.name}: the comparisons from step {start}", ("the reference's own step from "
                                                                                     "that state stops (the engine's "
                                                                                     "error)",))
            for start, history in zip(path.kept, segments) if not history]
    return {"params": params, "backend": backend, "candidate": candidate, "scene": path.scene.name,
            "starts": path.kept, "segments": segments, "rtol": DEFAULT_RTOL[path.scene.dtype.name],
            "dtype": path.scene.dtype.name, "stopped": path.stopped, "not_applicable": void,
            "exercised": tracker.items(),
            "ran": (f"Scene '{path.scene.name}' ({path.scene.dim}D, {path.scene.method.scheme}): {params.segment} "
                    f"steps on both backends from each of steps {', '.join(map(str, path.kept))} of the first "
                    f"{path.span} of its own {path.own} (run on {backend}), {step_text(path.scene)}.")}


def compare_from(scene, candidate, state, steps, tracker=None):
    """``steps`` steps of ``scene`` on the reference and on ``candidate`` from ``state``: the differences after each.
    A step that the engine stops (an instability, a particle out of the domain) ends the segment; one stopped on the
    candidate but not on the reference is an infinite difference, named by the error. ``tracker``
    (:class:`~verification.framework.coverage.Tracker`) sees every state compared."""
    ref, cand = resume(scene, "numpy", state), resume(scene, candidate, state)
    history = []
    if tracker is not None:
        tracker.see(ref.state)
    for _ in range(steps):
        dt = ref.stepper.time_step(ref.particles)
        try:
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", StabilityWarning)
                ref.step(dt)
        except MpmrefError:  # the reference stops too: nothing more to compare from this state
            break
        try:
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", StabilityWarning)
                cand.step(dt)
        except MpmrefError as exc:
            history.append({"the candidate's step": {f"raised {type(exc).__name__}": math.inf}})
            break
        history.append(differences(ref, cand, dt))
        if tracker is not None:
            tracker.see(ref.state)
    return history


def backends_run(result, backend):
    """The reference and the candidate."""
    return ("numpy", result["candidate"])


def checks(result):
    """One step within the conformance tolerance, up to ``segment`` steps within that many times it, from every kept
    state the reference steps from (module docstring)."""
    rtol, name = result["rtol"], f"{result['scene']} on {result['candidate']}"
    compared = [(start, history) for start, history in zip(result["starts"], result["segments"]) if history]
    if not compared:
        return []
    one, where, start = max((*worst(h[0]), s) for s, h in compared)
    traj, where_traj, start_traj = max((*worst(step), s) for s, h in compared for step in h)
    n = result["params"].segment
    return [Check(f"{name}: one step from {len(compared)} states of its run, max relative difference "
                  f"({where}, from step {start})", one, "<=", rtol,
                  f"same equations, different operation order: round-off ({result['dtype']} conformance bound)"),
            Check(f"{name}: {n}-step trajectories from {len(compared)} states of its run, max relative "
                  f"difference ({where_traj}, from step {start_traj})", traj, "<=", n * rtol,
                  "stable step, non-expansive transfers and return maps: n times the one-step bound")]


def findings(result):
    """What the compared states exercised (:mod:`verification.framework.coverage`: a field that stayed at round-off,
    a wall no particle reached, would not show a wrong code), and how the scene's own run on the backend stopped early,
    if it did: the segments start from the states it reached (the last good one among them)."""
    covered = [Finding(f"{result['scene']}: exercised, {item.name}", item.figure, item.sentence)
               for item in result.get("exercised", ())]
    if result["stopped"] is None:
        return covered
    return covered + [Finding(f"{result['scene']}: the scene's own run stopped at step", max(result["starts"]) + 1,
                    f"{result['stopped']}. Measured, not judged here: the comparisons start from the states it "
                    "reached, the last one just before it stopped.")]


def plot(result, path):
    """The largest relative difference against the step of each segment, with the bound."""
    n = np.arange(1, len(result["segments"][0]) + 1)
    floor = np.finfo(result["dtype"]).eps / 8  # exact agreement is drawn at this floor

    def draw(ax):
        for start, history in zip(result["starts"], result["segments"]):
            ax.semilogy(n[:len(history)], np.maximum([min(worst(h)[0], 1e300) for h in history], floor), "o-", ms=3,
                        label=f"from step {start}")
        ax.semilogy(n, n * result["rtol"], "k--", label=f"bound n·{result['rtol']:g}")

    return figure_with(draw, path, (
        f"{result['scene']}: the largest relative difference between the NumPy reference and {result['candidate']} "
        "(over materials and particle arrays) after each step, from the same particles at several steps of the "
        "scene's own run. Look for every curve under the dashed bound, growing at most linearly; exact agreement is "
        "drawn at the floor eps/8."),
        xlabel="step of the segment", ylabel="max relative difference",
        title=f"{result['scene']}: against the reference")


def report(result, out_dir):
    """Write the growth plot and ``reference.md``."""
    return write_report(out_dir, "reference", f"{result['scene']}: numpy against {result['candidate']}", result,
                        checks(result), plot)


#: this check, for ``mpmref verify --scene``
CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings, backends_run=backends_run)
