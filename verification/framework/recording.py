"""Runs measured at every step: :func:`record` steps a simulation to its end through
:meth:`mpmref.run.simulation.Simulation.run` and its ``each_step`` hook, keeping a row per state and evenly spaced
VTK frames."""

from dataclasses import dataclass
from time import perf_counter

from .report import snapshot

#: relative slack of a frame's time mark: a step that ends on it up to rounding takes the frame
MARK_SLACK = 1e-9


@dataclass(frozen=True)
class Recording:
    """What :func:`record` kept.

    Attributes
    ----------
    rows : list
        ``measure(sim)`` of the first state, then of the state after each step.
    frames : list
        ``frame(sim)`` of the first state, then at each mark reached.
    wall_s : float
        Wall time of the stepping, the measuring and the frames (not of the first row and frame).
    """

    rows: list
    frames: list
    wall_s: float


def record(sim, measure, frames, steps=None, t_end=None, dt=None, frame=snapshot):
    """Run ``sim`` for ``steps`` more steps or to the time ``t_end`` (one of them), measuring every state.

    Parameters
    ----------
    sim : mpmref.run.simulation.Simulation
        The simulation, stepped in place by :meth:`~mpmref.run.simulation.Simulation.run`.
    measure : callable
        ``measure(sim)``: the row of the current state, called at the start and after every step (before that
        step's frame, if any).
    frames : int
        How many frames after the first, evenly spaced: the k-th when the run has done ``k / frames`` of its
        ``steps`` (counted exactly) or reached ``k / frames`` of ``t_end`` (up to :data:`MARK_SLACK`); at most
        one a step, so a step that passes two marks takes one and the next step the other.
    steps : int, optional
        Steps to take now.
    t_end : float, optional
        Simulated time to stop at; each step is shortened so as not to pass it.
    dt : float, optional
        Δt of every step (default: the scene's rule).
    frame : callable, optional
        ``frame(sim)``: the frame of the current state (default: :func:`~verification.framework.report.snapshot`).

    Returns
    -------
    Recording
        The rows, the frames and the wall time.
    """
    rows, shots, first = [measure(sim)], [frame(sim)], sim.step_count

    def reached(k):
        if steps is not None:
            return (sim.step_count - first) * frames >= k * steps
        return sim.time >= k * (t_end / frames) * (1.0 - MARK_SLACK)

    def after_step(sim):
        rows.append(measure(sim))
        if reached(len(shots)):
            shots.append(frame(sim))

    start = perf_counter()
    sim.run(steps=steps, t_end=t_end, dt=dt, each_step=after_step)
    return Recording(rows, shots, perf_counter() - start)
