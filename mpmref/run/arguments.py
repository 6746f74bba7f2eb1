"""What a valid step size, step count and end time are: one definition for the Python API and the command line.

``Simulation.step(dt=...)``, ``Simulation.run(steps=..., t_end=...)`` and the options ``--steps`` and ``--t-end`` of
``mpmref run`` and ``mpmref study`` check their values here. Each function returns the value (as ``float`` or
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
