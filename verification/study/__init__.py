"""``mpmref study``: convergence and conservation studies of the user's own scene, one command from scene to slopes.

A study runs a scene file once for every combination of the values it varies (:mod:`.variations`), each run to
the same end time, and measures every run (:mod:`.runs`): the drifts of energy, momentum, angular momentum and
mass at the end and as time series, the energy ledger, steps, wall time, and the user's own measures. For every
resolution it varies (cells, Δt or CFL number, particles per cell) it measures the observed order of each
measure, fitted and by Richardson's estimate (:mod:`.orders`), and writes ``results.json``, ``results.csv``, the
plots and ``index.html`` (:mod:`.report`). Varied values that make the same computation (``method.scheme = apic``
and ``mls``: the APIC transfer with the MLS force, both) are named before any run, as a
:class:`SameComputationWarning`, and in the report. The runs go through
:class:`~verification.framework.executor.Executor`, like the sweeps of ``mpmref verify``; each writes its result
when it finishes, so a study stopped half-way keeps what is done, and running it again runs only the rest.
``docs/studying_your_scene.md`` is the chapter.

>>> from verification.study import run_study                                # doctest: +SKIP
>>> study = run_study("disk.toml", {"grid.cells": [16, 32, 64]}, t_end=0.1, out="reports/study/disk")
"""

import os
import pickle
import time
import warnings

from mpmref.backends import describe, make_backend
from mpmref.errors import ArgumentError

from ..framework.executor import Executor
from ..framework.report import machine
from .orders import ORDERED, observed_orders
from .plan import make_plan
from .report import write_report
from .runs import METRICS, finished, load, run
from .variations import Variation, label, parse_vary

__all__ = ["run_study", "make_plan", "parse_vary", "Variation", "SameComputationWarning", "Interrupted"]


class Interrupted(KeyboardInterrupt):
    """Ctrl-C stopped a study's runs (its workers are ended, :mod:`verification.framework.executor`): ``out`` keeps
    the results of ``finished`` of its ``total`` runs, and the study run again runs only the others."""

    def __init__(self, out, finished, total):
        super().__init__(out, finished, total)
        self.out, self.finished, self.total = out, finished, total


class SameComputationWarning(UserWarning):
    """Varied values whose runs make the same computation (:func:`verification.study.plan.same_computations`):
    the study runs each, and they give the same numbers."""


def run_study(scene, vary=(), t_end=None, *, backend="numpy", out=None, measures=(), exact=None,
              setup=None, frames=False, overwrite=False, ledger=True, executor=None, progress=None, announce=None):
    """Run a study of ``scene`` and write its report into ``out``; returns what ``results.json`` holds (with its
    ``paths``).

    Parameters
    ----------
    scene : str, Path or dict
        A TOML scene file, or its declarations as nested dicts.
    vary : dict or list of Variation
        ``{"grid.cells": [16, 32, 64], "method.scheme": ["apic", "mls"]}``: the product of the values;
        ``{("grid.cells", "time.dt"): [(16, 0.01), (32, 0.005)]}``: linked keys, varied together.
    t_end : float, optional
        Every run's end time (default: the scene's ``time.t_end``).
    backend : str
        A backend reference (:mod:`mpmref.backends`), resolved again in each worker.
    out : str or pathlib.Path, optional
        The report folder (default: ``reports/study/<scene name>``).
    measures : sequence
        ``MODULE:FUNCTION`` references (or, in a study run in this process, functions) ``f(sim) -> {name: value}``,
        called on each finished simulation.
    exact : str or function, optional
        ``f(scene, t) -> {name: value}``: the exact value of measures at time ``t`` of a run's scene; their orders
        are then measured against it.
    setup : str or function, optional
        ``f(sim)``, called on each new simulation before its first step (initial fields a scene cannot declare).
    frames : bool
        Write each run's VTK series into ``frames/<id>/``.
    overwrite : bool
        Run again the runs whose results an earlier study left in ``out`` (by default they are reused).
    ledger : bool
        Book the energy ledger in every synchronous run (it about doubles a NumPy run's time).
    executor : Executor, optional
        Where the runs go (default: this process).
    progress : callable, optional
        ``progress(done, total, run)``, called as each run finishes (the command line's progress bar).
    announce : callable, optional
        ``announce(runs)``, called with the runs still to do (the plan's: each with its validated ``scene`` and its
        ``spec``) before they start (the command line estimates their length there).
    """
    start = time.perf_counter()
    plan = make_plan(scene, vary, t_end, backend, out, measures, setup, frames, ledger)
    for message in plan.same:
        warnings.warn(message, SameComputationWarning, stacklevel=2)
    exact_fn = None if exact is None else load(exact, "exact")
    info = describe(backend, make_backend(backend, plan.runs[0]["scene"]))
    executor = executor or Executor(workers=1)
    _check_portable({"measure": list(measures), "setup": [setup]}, executor)
    results = _execute(plan, executor, overwrite, progress, announce)
    records = [_record(r, result, exact_fn) for r, result in zip(plan.runs, results)]
    user = list(dict.fromkeys(k for r in records for k in r.get("metrics", {}) if k not in METRICS
                              and not k.startswith("ledger_")))
    orders = observed_orders(records, plan.variations, list(ORDERED) + user, plan.eps)
    meta = {"scene": plan.source, "scene_name": plan.scene_name, "t_end": plan.runs[0]["spec"].t_end,
            "vary": [{"keys": list(v.keys), "levels": [list(level) for level in v.levels]} for v in plan.variations],
            "backend": info, "measures": [_name(m) for m in measures], "exact": _name(exact), "setup": _name(setup),
            "ledger": ledger, "same_computation": plan.same, "executor": executor.describe(),
            "wall_s": time.perf_counter() - start,
            "machine": machine()}
    paths = write_report(plan.out, meta, records, orders)
    return {**meta, "runs": records, "orders": orders, "paths": [str(p) for p in paths]}


def _check_portable(functions, executor):
    """Functions given as objects travel to the workers by name: refuse one that does not (a lambda, a function
    defined inside another) before any run, unless the runs stay in this process."""
    if executor.scheduler is None and executor.workers <= 1:
        return
    for option, given in functions.items():
        for fn in given:
            if fn is None or isinstance(fn, str):
                continue
            try:
                pickle.dumps(fn)
            except (pickle.PicklingError, AttributeError, TypeError):
                raise ArgumentError(option, _name(fn), "a function defined at the top level of an importable module "
                                    "when the runs go to other processes (or run them here: "
                                    "Executor(workers=1))") from None


def _execute(plan, executor, overwrite, progress, announce):
    """Every run's result: reused from an earlier study where one exists (unless ``overwrite``), else run (after
    ``announce`` of the runs to do)."""
    results = [None if overwrite else finished(r["spec"]) for r in plan.runs]
    for result in results:
        if result is not None:
            result["reused"] = True
    todo = [i for i, result in enumerate(results) if result is None]
    for spec in {os.path.dirname(plan.runs[i]["spec"].result) for i in todo}:
        os.makedirs(spec, exist_ok=True)

    if announce is not None and todo:
        announce([plan.runs[i] for i in todo])
    done = [0]
    if progress is not None:
        progress(0, len(todo), None)

    def arrived(j, result):
        results[todo[j]] = result
        done[0] += 1
        if progress is not None:
            progress(done[0], len(todo), label(plan.runs[todo[j]]["params"]))

    try:
        executor.map(run, [plan.runs[i]["spec"] for i in todo], on_result=arrived)
    except KeyboardInterrupt:
        raise Interrupted(plan.out, len(_kept(plan, results)), len(results)) from None
    return results


def _kept(plan, results):
    """The runs an interrupted study keeps: those whose results arrived, and those a worker finished writing before
    their results could arrive (what the same command will reuse, :func:`~.runs.finished`)."""
    found = [result if result is not None else finished(planned["spec"]) for planned, result in zip(plan.runs, results)]
    return [result for result in found if result is not None and not result.get("error")]


def _record(planned, result, exact_fn):
    """A run as the report and the orders see it: the plan's identity, parameters and abscissas with the result
    (``metrics``, ``series``; or ``error``) and the exact values of its measures."""
    frames = planned["spec"].frames is not None
    record = {"id": planned["id"], "params": planned["params"], "abscissa": planned["abscissa"], "exact": {},
              "error": result.get("error"), "reused": bool(result.get("reused")),
              "result": f"runs/{planned['id']}.json", "frames": f"frames/{planned['id']}" if frames else None}
    if "metrics" in result:
        record.update(metrics=result["metrics"], series=result["series"])
        if exact_fn is not None:
            record["exact"] = _exact_values(exact_fn, planned["scene"], result["metrics"]["final_time"])
    return record


def _exact_values(exact_fn, scene, t):
    values = exact_fn(scene, t)
    if not isinstance(values, dict):
        raise ArgumentError("exact", _name(exact_fn), f"a function returning a dict of named exact values, not "
                            f"{type(values).__name__}")
    return {k: float(v) for k, v in values.items()}


def _name(reference):
    """How a measure, exact or setup reference is named in the report."""
    if reference is None or isinstance(reference, str):
        return reference
    return f"{reference.__module__}:{reference.__qualname__}"
