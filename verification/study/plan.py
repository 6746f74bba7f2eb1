"""A study's plan: its runs, each a validated scene with its identity and files, made before any run starts.

Every combination of the variations becomes a :class:`~verification.study.runs.RunSpec` whose scene has been
validated and sampled (:func:`verification.study.variations.run_scene`), with two output settings of the study's
own: a diagnostics row every ``output.diagnostics_every`` steps (:data:`DIAGNOSTICS_EVERY` where the scene does not
declare it) and the energy ledger (unless the study is asked not to; an asynchronous scene's at its synchronised
times, with its ``interface`` term).
A run's files are named by its identity (:func:`~verification.study.runs.run_id`): ``runs/<id>.json`` and, with
frames, ``frames/<id>/``.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpmref.errors import ArgumentError
from mpmref.run import arguments
from mpmref.scene.builder import read_scene_file

from .orders import abscissa
from .runs import RunSpec, load, run_id
from .variations import Variation, combinations, run_scene

#: the study's diagnostics cadence where the scene declares none (a row every this many steps)
DIAGNOSTICS_EVERY = 10


@dataclass
class Plan:
    """The runs of a study and what they share.

    ``runs``: per run, ``params`` ({key: value}), ``spec`` (its :class:`~verification.study.runs.RunSpec`),
    ``scene`` (the validated :class:`~mpmref.scene.Scene`) and ``abscissa`` ({resolution key: (name, h)},
    :func:`verification.study.orders.abscissa`); ``eps``: machine epsilon of the scenes' dtype; ``out``: the
    report folder.
    """

    scene_name: str
    source: str
    variations: list
    runs: list
    eps: float
    out: Path


def make_plan(scene, vary, t_end, backend, out, measures=(), setup=None, frames=False, ledger=True):
    """The :class:`Plan` of a study of ``scene`` (a TOML path, or declarations as nested dicts).

    ``vary``: :class:`~verification.study.variations.Variation` objects, or ``{key: values}`` (a tuple of linked
    keys with tuples of values); ``t_end``: the end time of every run (default: the scene's ``time.t_end``); ``out``:
    the report folder (default: ``reports/study/<scene name>``). Raises
    :class:`~mpmref.errors.SceneError` for a run that is not a valid scene and
    :class:`~mpmref.errors.ArgumentError` for a reference that does not resolve or a missing end time.
    """
    declarations, base_dir, source = _declarations(scene)
    variations = [v if isinstance(v, Variation) else Variation.of(*v) for v in
                  (vary.items() if isinstance(vary, dict) else vary)]
    for reference in measures:
        load(reference, "measure")
    if setup is not None:
        load(setup, "setup")
    if t_end is not None:
        t_end = arguments.end_time(t_end, name="t_end")
    out = Path(out) if out is not None else Path("reports") / "study" / str(declarations.get("name", "scene"))
    runs = []
    for params in combinations(variations):
        data, run = run_scene(declarations, params, base_dir, extra=lambda d: study_output(d, ledger))
        end = t_end if t_end is not None else run.time.t_end
        if end is None:
            raise ArgumentError("t_end", None, "an end time: --t-end, or time.t_end in the scene (a study compares "
                                "runs at the same simulated time)")
        identity = run_id(data, end, backend, measures, setup)
        spec = RunSpec(params=tuple(params.items()), scene=data, base_dir=str(base_dir), t_end=end, backend=backend,
                       measures=tuple(measures), setup=setup, result=str(out / "runs" / f"{identity}.json"),
                       frames=str(out / "frames" / identity) if frames else None)
        runs.append({"id": identity, "params": params, "spec": spec, "scene": run,
                     "abscissa": {k: a for k in params if (a := abscissa(k, run)) is not None}})
    eps = max(float(np.finfo(r["scene"].dtype).eps) for r in runs)
    return Plan(runs[0]["scene"].name, source, variations, runs, eps, out)


def _declarations(scene):
    """``(declarations, base_dir, source)`` of a scene file or of declarations given as dicts."""
    if isinstance(scene, dict):
        return scene, Path.cwd(), "(declarations given in Python)"
    return read_scene_file(scene), Path(scene).parent, str(scene)


def study_output(data, ledger):
    """The study's output settings in a run's declarations ``data`` (the module docstring)."""
    output = data.setdefault("output", {})
    if not isinstance(output, dict):
        return  # the validator names it
    output.setdefault("diagnostics_every", DIAGNOSTICS_EVERY)
    if ledger:
        output["energy_ledger"] = True
