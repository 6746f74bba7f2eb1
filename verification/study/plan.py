"""A study's plan: its runs, each a validated scene with its identity and files, made before any run starts.

Every combination of the variations becomes a :class:`~verification.study.runs.RunSpec` whose scene has been
validated and sampled (:func:`verification.study.variations.run_scene`), with two output settings of the study's
own: a diagnostics row every ``output.diagnostics_every`` steps (:data:`DIAGNOSTICS_EVERY` where the scene does not
declare it) and the energy ledger (unless the study is asked not to; an asynchronous scene's at its synchronised
times, with its ``interface`` term).
A run's files are named by its identity (:func:`~verification.study.runs.run_id`): ``runs/<id>.json`` and, with
frames, ``frames/<id>/``.

Runs whose varied values make the same computation are found here too (:func:`same_computations`): their
validated scenes are compared as they are computed (:func:`computation`: the method as resolved, names left out),
so ``method.scheme = apic`` and ``mls`` (the APIC transfer with the MLS force, both) or ``E = 5000`` and ``5000.0``
are named before any run, with what they both resolve to.
"""

import dataclasses
import json
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpmref.errors import ArgumentError
from mpmref.run import arguments
from mpmref.scene.builder import read_scene_file

from .orders import abscissa
from .runs import RunSpec, load, run_id
from .variations import Variation, combinations, key_path, run_scene

#: the study's diagnostics cadence where the scene declares none (a row every this many steps)
DIAGNOSTICS_EVERY = 10


@dataclass
class Plan:
    """The runs of a study and what they share.

    ``runs``: per run, ``params`` ({key: value}), ``spec`` (its :class:`~verification.study.runs.RunSpec`),
    ``scene`` (the validated :class:`~mpmref.scene.Scene`) and ``abscissa`` ({resolution key: (name, h)},
    :func:`verification.study.orders.abscissa`); ``eps``: machine epsilon of the scenes' dtype; ``out``: the
    report folder; ``same``: a message for each set of varied values that make the same computation
    (:func:`same_computations`).
    """

    scene_name: str
    source: str
    variations: list
    runs: list
    eps: float
    out: Path
    same: list = dataclasses.field(default_factory=list)


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
    return Plan(runs[0]["scene"].name, source, variations, runs, eps, out, same_computations(runs))


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


# ------------------------------------------------------------------------------------------- the same computation
#: the fields of a validated :class:`~mpmref.scene.Scene` that are not what its runs compute: its name, the
#: declarations as given (validated into the other fields), the folder its file paths were resolved from, and the
#: method as declared (:func:`computation` puts the resolved transfer in its place)
NOT_COMPUTED = ("name", "source", "base_dir", "method")
#: how the report names a resolved transfer and force
TRANSFER_NAMES = {"pic": "PIC", "flip": "FLIP", "apic": "APIC", "polypic": "PolyPIC"}
FORCE_NAMES = {"mls": "MLS", "classic": "classic (∇w)"}


def computation(scene):
    """What the runs of a validated ``scene`` compute, as a JSON text: every field of the scene but
    :data:`NOT_COMPUTED`, and its method as resolved (:attr:`~mpmref.scene.Scene.transfer`: transfer, force,
    kernel, velocity gradient, FLIP fraction, tracked state) without the declared scheme's name, which the
    resolution keeps for reports. Two scenes with the same text run the same computation."""
    fields = {f.name: plain(getattr(scene, f.name)) for f in dataclasses.fields(scene) if f.name not in NOT_COMPUTED}
    fields["transfer"] = plain(scene.transfer._replace(scheme=None))
    return json.dumps(fields, sort_keys=True)


def plain(value):
    """``value`` as JSON values, its type named where it is an object (a Neo-Hookean and a fixed-corotated material
    with the same parameters differ), arrays in full."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
        return {"type": type(value).__name__, **fields}
    if isinstance(value, tuple) and hasattr(value, "_asdict"):
        return {"type": type(value).__name__, **plain(value._asdict())}
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return {"dtype": str(value.dtype), "values": value.tolist()}
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if hasattr(value, "__dict__"):
        return {"type": type(value).__name__, **plain(vars(value))}
    return repr(value)


def same_computations(runs):
    """A message for each set of varied values whose runs make the same computation (:func:`computation`), naming
    the values and what they resolve to: such runs give the same numbers, so the study runs them for nothing."""
    groups = defaultdict(list)
    for run in runs:
        groups[computation(run["scene"])].append(run)
    messages = {}
    for group in (g for g in groups.values() if len(g) > 1):
        keys = [k for k in group[0]["params"] if len({repr(r["params"][k]) for r in group}) > 1]
        values = "; ".join(f"{k} = {' and '.join(str(r['params'][k]) for r in group)}" for k in keys)
        sections = dict.fromkeys(str(key_path(k)[0]) for k in keys)
        why = ", ".join(resolved(section, group[0]["scene"]) for section in sections)
        messages.setdefault(values, f"{values} resolve to the same {why}, so their runs compute the same numbers "
                                    "(vary what changes the computation, or keep one of them)")
    return list(messages.values())


def resolved(section, scene):
    """What the ``section`` of a validated scene (a top-level key: ``method``, ``grid``, ``materials``, ...)
    resolves to, in words for the method and as its values otherwise (shortened)."""
    if section == "method":
        t = scene.transfer
        transfer = TRANSFER_NAMES[t.transfer] + (f" (α = {t.flip_alpha})" if t.flip else "")
        return (f"method: {transfer} transfer with the {FORCE_NAMES[t.force]} force ({t.kernel} kernel, "
                f"{FORCE_NAMES[t.gradient]} velocity gradient)")
    text = json.dumps(plain(getattr(scene, section, None)))
    return f"{section}: {text if len(text) <= 160 else text[:157] + '...'}"
