"""What a valid step size, step count and end time are: one definition for the Python API and the command line.

``Simulation.step(dt=...)``, ``Simulation.run(steps=..., until_step=..., t_end=..., dt=...)`` and the options
``--steps``, ``--until-step`` and ``--t-end`` of ``mpmref run`` (``--t-end`` of ``mpmref study``) check their values
here, and :func:`stop` is the one rule of what a run's stop means. Each function returns the value (as ``float`` or
``int``) or raises :class:`~mpmref.errors.ArgumentError` (a ``ValueError``) naming the argument, the value and what
is allowed; the command line reports the same text with exit status 2.
"""

import math
import numbers

from ..errors import ArgumentError


def time_step(value, name="dt"):
    """A step size: a finite number > 0 (a step never goes backwards or stands still)."""
    if not _real(value) or not (math.isfinite(value) and value > 0):
        raise ArgumentError(name, value, "a finite number > 0 (the step size)")
    return float(value)


def step_count(value, name="steps"):
    """A number of steps: an integer >= 0."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 0:
        raise ArgumentError(name, value, "an integer >= 0")
    return int(value)


def thread_count(value, name="threads"):
    """A number of threads: an integer >= 1."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ArgumentError(name, value, "an integer >= 1")
    return int(value)


def stop(steps, until_step, t_end, step_now, time_now):
    """The stop of a run as ``(steps to take, t_end)``, from at most one of ``steps`` (more steps), ``until_step``
    (the step count to stop at, a total) and ``t_end`` (the time to stop at); ``(None, None)`` if none is given.
    Two at once, or a value out of its range, is an :class:`~mpmref.errors.ArgumentError`."""
    given = {name: value for name, value in (("steps", steps), ("until_step", until_step), ("t_end", t_end))
             if value is not None}
    if len(given) > 1:
        raise ArgumentError(" and ".join(given), tuple(given.values()), "one of steps (more steps), until_step (the "
                            "step to stop at) and t_end (the time to stop at)")
    if until_step is not None:
        return max(0, step_count(until_step, "until_step") - step_now), None
    if steps is not None:
        return step_count(steps), None
    return None, None if t_end is None else end_time(t_end, time_now)


def end_time(value, now=0.0, name="t_end", after=False):
    """An end time: a finite number >= ``now``, the current simulated time (a run never goes backwards); with
    ``after``, > ``now`` (the end of a step, which must advance)."""
    if not _real(value) or not (math.isfinite(value) and (value > now if after else value >= now)):
        relation = ">" if after else ">="
        what = "the current simulated time" if now else "simulated time"
        raise ArgumentError(name, value, f"a finite number {relation} {now:.17g} ({what})")
    return float(value)


def _real(value):
    return isinstance(value, numbers.Real) and not isinstance(value, bool)
