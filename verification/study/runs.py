r"""One run of a study: its scene run to the end time, and what it measures, at the end and as time series.

A run records the diagnostics of :meth:`mpmref.run.simulation.Simulation.run` (``record=True``) every
``output.diagnostics_every`` steps and turns each row into the drifts of the conserved quantities, with
:math:`E` the total energy (kinetic, affine, PolyPIC modes, elastic, gravitational), :math:`P` the linear and
:math:`L` the angular momentum (affine part included, about the origin), :math:`M` the mass:

.. math::

    \texttt{energy\_change}(t) = \frac{E(t) - E(0)}{E(0)}, \qquad
    \texttt{momentum\_drift}(t) = \frac{|P(t) - P(0)|}{S_P}, \qquad
    \texttt{angular\_momentum\_drift}(t) = \frac{|L(t) - L(0)|}{S_L}, \qquad
    \texttt{mass\_drift}(t) = \frac{M(t) - M(0)}{M(0)},

with the scales :math:`S_P = \sum_p m_p |v_p|` (:func:`mpmref.observe.diagnostics.momentum_scale`) and :math:`S_L`, the
sum of the magnitudes of the parts of :math:`L` about the centre of mass
(:func:`mpmref.observe.diagnostics.angular_momentum_scale`), each the larger of its values in the first and the last
state: what the particles' contributions could add up to, so that a spinning disk, whose :math:`P` is zero,
still has a scale, and a rigid rotation's angular momentum drift is its relative change (a drift is 0 when
nothing changed, also when everything is at rest). ``energy_excursion`` is the largest
:math:`|E(t) - E(0)| / |E(0)|` of the series. Where the scene steps synchronously the study books the energy
ledger (:mod:`mpmref.observe.ledger`), and ``ledger_<term>`` is each term's cumulative change over :math:`E(0)`: the
terms add up to ``energy_change`` (plus the rigid bodies' energy change, which :math:`E` leaves out).

The user's measures are functions of the finished :class:`~mpmref.run.simulation.Simulation` returning named
scalars; a ``setup`` function of the new simulation sets initial fields a scene cannot declare. Each is a
``MODULE:FUNCTION`` reference (resolved again in the worker) or, in a study run in this process, a function.
"""

import hashlib
import inspect
import json
import math
import numbers
import pkgutil
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpmref import Scene, Simulation
from mpmref.errors import ArgumentError
from mpmref.io.atomic import write_text_atomic
from mpmref.io.run_output import clear_run
from mpmref.observe.diagnostics import angular_momentum_scale, momentum_scale
from mpmref.observe.ledger import ASYNC_TERMS

from ..framework.report import json_number

#: schema of a run's result file, ``runs/<id>.json``
RUN_SCHEMA = "mpmref-study-run/1"
#: the drifts of the conserved quantities, per row and at the end
DRIFTS = ("energy_change", "momentum_drift", "angular_momentum_drift", "mass_drift")
#: the metrics every run reports (before the ledger's and the user's)
METRICS = DRIFTS + ("energy_excursion", "final_time", "steps", "particles", "wall_s", "particle_steps_per_s")


@dataclass(frozen=True)
class RunSpec:
    """One run of a study (picklable, for :class:`~verification.framework.executor.Executor`).

    ``params``: its ``(key, value)`` pairs; ``scene``: its declarations (the variation applied); ``measures`` and
    ``setup``: references (or functions, in this process); ``result``: the path of its JSON; ``frames``: the
    folder of its VTK series, or ``None``.
    """

    params: tuple
    scene: dict
    base_dir: str
    t_end: float
    backend: str
    measures: tuple
    setup: object
    result: str
    frames: str | None = None


def load(reference, option):
    """The function that ``reference`` (``MODULE:FUNCTION``, or a function) names; :class:`ArgumentError` naming
    ``option`` when it does not import or is not callable."""
    if callable(reference):
        return reference
    allowed = ("MODULE:FUNCTION naming a function importable from this Python (installed, on PYTHONPATH or in "
               "the current folder)")
    if not isinstance(reference, str) or ":" not in reference:
        raise ArgumentError(option, reference, allowed)
    try:
        found = pkgutil.resolve_name(reference)
    except (ImportError, AttributeError, ValueError) as exc:
        raise ArgumentError(option, reference, f"{allowed}; it does not resolve: {exc}") from None
    if not callable(found):
        raise ArgumentError(option, reference, f"{allowed}; it names a {type(found).__name__}")
    return found


def fingerprint(reference):
    """What identifies a measure or setup in a run's identity: its reference and, where Python has it, a hash of its
    source (so that results measured by an older version of the function are not reused)."""
    if reference is None:
        return None
    fn = load(reference, "measure")
    name = reference if isinstance(reference, str) else f"{fn.__module__}:{fn.__qualname__}"
    try:
        source = inspect.getsource(fn)
    except (OSError, TypeError):
        return name
    return f"{name}#{hashlib.sha256(source.encode()).hexdigest()[:12]}"


def run_id(scene, t_end, backend, measures, setup):
    """The identity of a run (hex): a hash of everything its results depend on."""
    identity = {"scene": scene, "t_end": t_end, "backend": backend, "setup": fingerprint(setup),
                "measures": [fingerprint(m) for m in measures]}
    return hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()[:16]


def finished(spec):
    """The result of ``spec`` written by an earlier study (``None`` if there is none, or its frames are missing)."""
    path = Path(spec.result)
    if not path.is_file() or (spec.frames is not None and not (Path(spec.frames) / "particles.pvd").is_file()):
        return None
    return json.loads(path.read_text(), object_hook=_non_finite)


def run(spec):
    """Run ``spec``, write its result to ``spec.result`` and return it; a run that fails returns its parameters
    and ``error`` (the traceback) instead, and writes nothing (a later study runs it again)."""
    try:
        result = {"schema": RUN_SCHEMA, "id": Path(spec.result).stem, "params": dict(spec.params), **measure(spec)}
    except Exception:  # one failed run (an instability, a bad measure) must not stop the others
        return {"params": dict(spec.params), "error": traceback.format_exc()}
    text = json.dumps(jsonable(result), indent=1, allow_nan=False)
    write_text_atomic(spec.result, text + "\n")
    return json.loads(text, object_hook=_non_finite)  # as a later study reads it back (finished)


def measure(spec):
    """Simulate ``spec`` and return its ``metrics`` and ``series`` (the module docstring)."""
    scene = Scene.from_dict(spec.scene, base_dir=spec.base_dir)
    if spec.frames is not None:
        clear_run(spec.frames)
    sim = Simulation(scene, backend=spec.backend, out_dir=spec.frames)
    if spec.setup is not None:
        load(spec.setup, "setup")(sim)
    sim.warm_up()
    n, first = sim.n_particles, scales(sim)
    summary = sim.run(t_end=spec.t_end, record=True)
    last = scales(sim)
    series = drift_series(summary["series"], max(first[0], last[0]), max(first[1], last[1]))
    metrics = {**{k: series[k][-1] for k in DRIFTS + tuple(k for k in series if k.startswith("ledger_"))},
               "energy_excursion": float(np.max(np.abs(series["energy_change"]))), "final_time": sim.time,
               "steps": summary["steps"], "particles": n, "wall_s": summary["wall_s"],
               "particle_steps_per_s": summary["particle_steps_per_s"]}
    for reference in spec.measures:
        metrics.update(user_measure(reference, sim, metrics))
    return {"metrics": metrics, "series": series, "backend": sim.backend_info, "t_end": spec.t_end}


def scales(sim):
    """``(S_P, S_L)`` of the current state (the module docstring)."""
    return momentum_scale(sim.particles), angular_momentum_scale(sim.particles, sim.inertia)


def drift_series(rows, momentum_scale_, angular_scale):
    """The drifts of the module docstring per diagnostics row, with ``time``, ``step``, ``total_energy`` and, with
    the ledger, ``ledger_<term>`` over :math:`E(0)`: columns (lists of floats).

    Docs: docs/studying_your_scene.md#what-each-run-measures
    """
    column = lambda key: np.array([row[key] for row in rows], dtype=np.float64)
    vector = lambda prefix: np.stack([column(k) for k in rows[0] if k.startswith(prefix)], axis=1)
    energy, mass = column("total_energy"), column("mass")
    P, L = vector("momentum_"), vector("angular_momentum")
    out = {"time": column("time"), "step": column("step"), "total_energy": energy,
           "energy_change": ratio(energy - energy[0], energy[0]),
           "momentum_drift": ratio(np.linalg.norm(P - P[0], axis=1), momentum_scale_),
           "angular_momentum_drift": ratio(np.linalg.norm(L - L[0], axis=1), angular_scale),
           "mass_drift": ratio(mass - mass[0], mass[0])}
    out.update({f"ledger_{t}": ratio(column(f"ledger_{t}"), energy[0])
                for t in ASYNC_TERMS if f"ledger_{t}" in rows[0]})
    return {k: [float(x) for x in v] for k, v in out.items()}


def ratio(change, scale):
    """``change / scale`` elementwise, 0 where nothing changed (also when the scale is 0: nothing moved)."""
    change = np.asarray(change, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(change == 0.0, 0.0, change / scale)


def user_measure(reference, sim, metrics):
    """The named scalars ``reference`` measures on the finished ``sim``, checked: a mapping of new names to real
    numbers (as floats)."""
    values = load(reference, "measure")(sim)
    name = reference if isinstance(reference, str) else reference.__qualname__
    if not isinstance(values, dict) or not values:
        raise ArgumentError("measure", name, f"a function returning a non-empty dict of named scalars, not "
                            f"{type(values).__name__}")
    for key, value in values.items():
        if not isinstance(key, str) or key in metrics:
            raise ArgumentError("measure", name, f"names that are new strings ({key!r} is not: the run already has "
                                f"{', '.join(metrics)})")
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ArgumentError("measure", name, f"real numbers as values ({key!r} is {value!r})")
    return {key: float(value) for key, value in values.items()}


def _non_finite(table):
    """A JSON object with the strings ``"nan"``, ``"inf"`` and ``"-inf"`` of :func:`jsonable` as floats again."""
    back = lambda v: float(v) if isinstance(v, str) and v in NON_FINITE else v
    return {k: [back(x) for x in v] if isinstance(v, list) else back(v) for k, v in table.items()}


#: how :func:`~verification.framework.report.json_number` writes the floats JSON has no numbers for
NON_FINITE = ("nan", "inf", "-inf")


def jsonable(data):
    """``data`` with every float as :func:`~verification.framework.report.json_number` writes it (NaN and infinities as
    the strings ``"nan"``, ``"inf"``, ``"-inf"``, so the file stays standard JSON)."""
    if isinstance(data, dict):
        return {k: jsonable(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [jsonable(v) for v in data]
    if isinstance(data, float) and not math.isfinite(data):
        return json_number(data)
    return data
