"""Run a candidate backend on the conformance cases and compare each stage with the NumPy reference.

A case runs when the candidate implements what its stage depends on (:meth:`~mpmref.backends.capabilities.Implements.
missing` of the case's parts, :attr:`~.case.ConformanceCase.parts`), its factory makes the case's scene and it provides
the stage; otherwise it is *not applicable*, with the reasons (:class:`NotApplicable`), which is never a failure. A
stage that raises :class:`NotImplementedError` declines its case the same way; any other exception fails the case and
names the stage and the scene.
"""

import json
import math
import numbers
import sys
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from ..backends import refuse_missing_device, resolve
from ..backends.capabilities import EVOLVED, declined
from ..errors import ArgumentError
from ..steppers.limits import wave_speeds
from .candidates import candidate_implements, stage_set, validated
from .cases import make_cases
from .diagnosis import NODE_PREFIXES, compared_rows, restrict, uniform_ratio, worst_place, worst_row
from .measures import judged_error, natural_scales
from .stages import ALL_CONFORMANCE_STAGES, optional_outputs, particles_from, run_stage
from .states import rest_wave_speeds


def compare_outputs(got, expected, rows=None, natural=None):
    """Per-output errors of ``got`` against ``expected`` (each an :class:`OutputError`: per row and case-wide,
    :func:`judged_error`) and a note on missing or misshapen outputs.

    ``rows`` (:func:`.diagnosis.compared_rows`) restricts ``F``, ``J`` and ``Jp`` to the particles whose material
    evolves them; a misshapen output is compared whole (and fails); a ledger term is compared relative to the
    reference's energy scale (:func:`.measures.output_scale`); ``natural`` (:func:`.measures.natural_scales`) gives
    the outputs summed from larger terms, or made of a stiffness, the scale of their floor."""
    rows, natural = rows or {}, natural or {}
    errors, problems = {}, []
    for name, ref in expected.items():
        value = got.get(name)
        if value is None:
            errors[name] = math.inf
            problems.append(f"no output {name}")
            continue
        if np.shape(value) != np.shape(ref):
            errors[name] = math.inf
            problems.append(f"{name} has shape {np.shape(value)}, expected {np.shape(ref)}")
            continue
        errors[name] = judged_error(name, restrict(name, value, rows), restrict(name, ref, rows), expected,
                                    natural.get(name, 0.0))
    return errors, "; ".join(problems)


@dataclass(frozen=True)
class CaseResult:
    """The outcome of one case: the relative error of each output, the threshold and any problem met.

    ``error`` is the largest output error (``inf`` when no output could be compared, e.g. the candidate
    raised); the case passes when ``error <= rtol``. ``setting`` says what the case ran on (method, materials with
    their parameters, walls, Δt and time: :func:`describe_setting`), for the failure lines.
    """

    case: object
    errors: dict
    rtol: float
    note: str = ""
    where: str = ""  # the worst output's worst particle or node (:func:`.diagnosis.worst_place`)
    ratio: float | None = None  # the worst output is this factor times the reference everywhere, if it is
    setting: str = ""
    holds: str = ""  # for a case at an extreme, what its worst particle holds (:func:`held_extreme`)

    @property
    def error(self):
        return max(self.errors.values(), default=math.inf)

    @property
    def worst_output(self):
        return max(self.errors, key=self.errors.get, default="")

    @property
    def passed(self):
        return self.error <= self.rtol


@dataclass(frozen=True)
class NotApplicable:
    """A case the candidate does not implement: ``reasons`` in words, and their ``kind``: ``"declared"`` (its
    :class:`~mpmref.backends.capabilities.Implements` lacks what the case needs), ``"declined"`` (its factory or
    the stage raised :class:`NotImplementedError`) or ``"not provided"`` (it has no such stage)."""

    case: object
    reasons: tuple
    kind: str


@dataclass
class Report:
    """Results of :func:`check`: one :class:`CaseResult` per case run, one :class:`NotApplicable` per case that does
    not apply to the candidate, and the candidate's declaration (``implements``)."""

    results: list
    not_applicable: list = field(default_factory=list)
    implements: object = None

    @property
    def passed(self):
        """True when at least one case ran and every case that ran passed (a case that does not apply is neither)."""
        return bool(self.results) and all(r.passed for r in self.results)

    @property
    def skipped(self):
        """The cases whose stage the candidate does not provide."""
        return [n.case for n in self.not_applicable if n.kind == "not provided"]

    def failures(self):
        return [r for r in self.results if not r.passed]

    def failed_stages(self):
        return {r.case.stage for r in self.failures()}

    def worst(self):
        """The result furthest from passing (largest ``error / rtol``), or ``None`` if nothing ran."""
        return max(self.results, key=lambda r: r.error / r.rtol, default=None)

    def stage_summary(self):
        """Per stage with a case: ``{stage: (passed, failed, not applicable, worst CaseResult or None)}`` in stage
        order."""
        summary = {}
        for stage in ALL_CONFORMANCE_STAGES:
            rows = [r for r in self.results if r.case.stage == stage]
            skipped = sum(n.case.stage == stage for n in self.not_applicable)
            if rows or skipped:
                failed = sum(not r.passed for r in rows)
                worst = max(rows, key=lambda r: r.error / r.rtol, default=None)
                summary[stage] = (len(rows) - failed, failed, skipped, worst)
        return summary

    def reasons(self):
        """``{reason: [stages]}`` of the cases that do not apply, most frequent reason first; a case with several
        reasons counts under each, and each reason's stages are listed once each, in stage order."""
        count = Counter(reason for n in self.not_applicable for reason in n.reasons)
        stages = {}
        for n in self.not_applicable:
            for reason in n.reasons:
                stages.setdefault(reason, set()).add(n.case.stage)
        return {reason: (count[reason], sorted(stages[reason], key=ALL_CONFORMANCE_STAGES.index))
                for reason, _ in count.most_common()}

    def table(self, verbose=False):
        """A readable text table: one line per stage (passed, failed and not applicable cases, the largest error and
        the worst case), the reasons of the cases that do not apply, then the failed cases with every output's error
        and what they ran on (every case if ``verbose``)."""
        lines = [f"{'stage':<16} {'passed':>6} {'failed':>6} {'n/a':>5} {'max rel. error':>14} {'rtol':>8}  "
                 "worst case (output)"]
        for stage, (passed, failed, skipped, worst) in self.stage_summary().items():
            figures = (f"{worst.error:>14.3e} {worst.rtol:>8.0e}  {worst.case.name} ({worst.worst_output})"
                       if worst else f"{'-':>14} {'-':>8}")
            lines.append(f"{stage:<16} {passed:>6} {failed:>6} {skipped:>5} {figures}")
        if self.not_applicable:
            lines.append(f"not applicable: {len(self.not_applicable)} cases, by reason (a case may have several):")
            lines += [f"  {reason}: {count} case{'s' if count > 1 else ''} ({', '.join(stages)})"
                      for reason, (count, stages) in self.reasons().items()]
        rows = self.results if verbose else self.failures()
        width = max((len(r.case.name) for r in rows), default=0)
        if rows:
            lines.append("cases:" if verbose else "failed cases:")
            lines += [line for r in rows for line in _case_lines(r, width)]
        if verbose and self.not_applicable:
            lines.append("not applicable cases:")
            lines += [f"  n/a  {n.case.name}: {'; '.join(n.reasons)}" for n in self.not_applicable]
        lines.append(self.verdict())
        return "\n".join(lines)

    def verdict(self):
        """The last line of the table: ``PASSED: k of n cases within tolerance`` (or ``FAILED``), with the count of the
        cases that do not apply."""
        ran, failed = len(self.results), len(self.failures())
        word = "PASSED" if self.passed else "FAILED"
        text = f"{word}: {ran - failed} of {ran} cases within tolerance"
        if self.not_applicable:
            text += f"; {len(self.not_applicable)} not applicable"
        return text if ran else f"{text} (no case applies to this candidate: nothing was checked)"


def _case_lines(result, width):
    """A case's line (status, name, worst output, its error, where, the uniform ratio) and, for a failed case, every
    output's error and the setting it ran on."""
    status = "ok  " if result.passed else "FAIL"
    details = [result.note] if result.note else []
    if not result.passed and result.where:
        details.append(f"worst at {result.where}")
    if not result.passed and result.ratio is not None:
        details.append(f"× {result.ratio:.6g} everywhere")
    note = f"  {'; '.join(details)}" if details else ""
    lines = [f"  {status} {result.case.name:<{width}} {result.worst_output:<14} {result.error:.3e}{note}"]
    if not result.passed:
        if result.holds:
            lines[0] = f"  {status} {result.case.name} ({result.holds}): {result.worst_output} {result.error:.3e}{note}"
        if result.errors:
            lines.append("       outputs: " + ", ".join(_output_error(k, e) for k, e in result.errors.items()))
        if result.setting:
            lines.append(f"       setting: {result.setting}")
    return lines


def _output_error(name, error):
    """``"tau 1.600e-09"``, with the case-wide error after it where the per-row one is larger
    (:class:`.measures.OutputError`)."""
    case_wide = getattr(error, "case_wide", error)
    return f"{name} {error:.3e}" + (f" (case-wide {case_wide:.3e})" if case_wide < error else "")


def held_extreme(case, row):
    """What ``case``'s particle ``row`` holds at its extreme (``"|S₀₁| = 1e-07 at particle 16"``), or what the case
    holds (:attr:`~.extremes.Extreme.holds`) where that row has no note; ``""`` for a case without an extreme."""
    if case.extreme is None:
        return ""
    notes = case.notes()
    if notes is not None and row is not None and row < len(notes) and notes[row]:
        return f"{notes[row]} at particle {row}"
    return case.extreme.holds


def describe_setting(case, scene, inputs):
    """What ``case`` ran on, in one line: its method, its materials with their parameters (as declared, defaults
    filled in), the walls and colliders where its stage sees them, Δt and the time."""
    method = scene.method
    gradient = "" if method.velocity_gradient == method.force else f", velocity gradient {method.velocity_gradient}"
    parts = [f"method {method.scheme} (force {method.force}, kernel {method.kernel}{gradient})"]
    materials = []
    for name, material in scene.materials.items():
        declared = case.scene_dict["materials"][name]
        values = ", ".join(f"{k} = {getattr(material, k):g}" for k in declared if k != "type" and hasattr(material, k))
        named = declared["type"] if name == declared["type"] else f"{name}: {declared['type']}"
        materials.append(f"{named} ({values})")
    parts.append("materials " + "; ".join(materials))
    if "boundary" in case.parts:
        walls = {face: w.type + (f" (friction {w.friction:g})" if w.type == "separate" else "")
                 for face, w in scene.boundary.walls.items()}
        kinds = set(walls.values())
        where = (f"{kinds.pop()} on every face" if len(kinds) == 1
                 else ", ".join(f"{face} {kind}" for face, kind in walls.items()))
        parts.append(f"walls ({scene.boundary.width} nodes): {where}")
        if scene.colliders:
            shapes = (f"{type(c.shape).__name__.lower()} {c.type}" for c in scene.colliders)
            parts.append("colliders: " + ", ".join(shapes))
    parts += [f"{key} = {float(inputs[key]):.6g}" for key in ("dt", "time") if key in inputs]
    if case.source:
        parts.append(f"drawn from scene {case.source!r}")
    return "; ".join(parts)


# ------------------------------------------------------------------------------------------------ check
def stage_functions(candidate, scene):
    """The candidate's stage callables for ``scene`` as ``{stage: callable}`` (see :mod:`mpmref.conformance`).

    ``candidate`` is a backend reference of :mod:`mpmref.backends` (a built-in or plugin name, or
    ``"MODULE:ATTRIBUTE"``, resolved to what it names), a factory ``factory(scene)`` returning an object with stage
    methods or a mapping of stage names to callables, or a mapping of stage names to callables that take the
    scene first. Unlike :func:`mpmref.backends.make_backend`, a candidate may lack stages: those are not applicable.
    (A backend object is made for one scene, and every case has its own: give its factory.)
    """
    return stage_set(resolve(candidate), scene).functions


class Candidate:
    """A resolved candidate, with what it made for each distinct scene (a factory is called once per scene)."""

    def __init__(self, found, implements):
        self.found, self.implements, self.made = found, implements, {}

    def stages_for(self, case):
        """The :class:`~.candidates.StageSet` for ``case``'s scene, or the :class:`NotApplicable` of a factory that
        declined it, or the note of a factory that raised."""
        key = json.dumps(case.scene_dict, sort_keys=True)
        if key not in self.made:
            try:
                self.made[key] = stage_set(self.found, case.scene())
            except NotImplementedError as exc:
                self.made[key] = ("declined", declined(exc))
            except Exception as exc:  # a factory that fails on a scene it implements fails that scene's cases
                self.made[key] = ("error", f"the factory raised {type(exc).__name__}: {exc} (for scene "
                                           f"{case.scene_dict.get('name')!r})")
        return self.made[key]

    def run(self, case, rtol):
        """The :class:`CaseResult` or :class:`NotApplicable` of ``case``."""
        scene = case.parsed_scene()
        reasons = self.implements.missing(scene, case.parts)
        if reasons:
            return NotApplicable(case, tuple(reasons), "declared")
        made = self.stages_for(case)
        if isinstance(made, tuple):
            kind, text = made
            if kind == "declined":
                return NotApplicable(case, (text,), "declined")
            return CaseResult(case, {}, rtol, note=text)
        reasons = made.implements.missing(scene, case.parts)
        if reasons:
            return NotApplicable(case, tuple(reasons), "declared")
        fn = made.functions.get(case.stage)
        if fn is None:
            return NotApplicable(case, (made.absent.get(case.stage, f"does not provide the stage {case.stage}"),),
                                 "not provided")
        evolves = set(self.implements.evolves) & set(made.implements.evolves)
        return _run_case(fn, case, scene, rtol, evolves)


def _run_case(fn, case, scene, rtol, evolves):
    inputs = case.inputs()
    expected = case.reference(inputs)
    setting = describe_setting(case, scene, inputs)
    try:
        got = run_stage(case.stage, fn, inputs)
    except NotImplementedError as exc:
        return NotApplicable(case, (f"its stage {case.stage} raised NotImplementedError: {declined(exc)}",),
                             "declined")
    except Exception as exc:  # a candidate that raises is a failed case to report, not a crash of the harness
        note = (f"stage {case.stage} raised {type(exc).__name__}: {exc} (scene {case.scene_dict.get('name')!r}, "
                f"case {case.name})")
        return CaseResult(case, {}, rtol, note=note, setting=setting)
    expected = {k: v for k, v in expected.items() if k not in EVOLVED or k in evolves}  # fields it does not evolve
    optional = optional_outputs(case.stage, fn)  # outputs the candidate does not give by design
    expected = {k: v for k, v in expected.items() if k not in optional}
    rows = compared_rows(scene, inputs)
    errors, note = compare_outputs(got, expected, rows, case_natural_scales(scene, inputs, expected))
    result = CaseResult(case, errors, rtol, note, setting=setting)
    worst = result.worst_output
    if result.passed or worst not in got:
        return result
    where = worst_place(worst, got[worst], expected[worst], rows, scene, inputs)
    ratio = uniform_ratio(worst, got[worst], expected[worst], rows)
    particle = "x" in inputs and not worst.startswith(NODE_PREFIXES)  # notes are the particles'
    holds = held_extreme(case, worst_row(worst, got[worst], expected[worst], rows) if particle else None)
    return CaseResult(case, errors, rtol, note, where=where, ratio=ratio, setting=setting, holds=holds)


def case_natural_scales(scene, inputs, expected):
    r"""The natural scales of a case's outputs (:func:`.measures.natural_scales`): from its inputs, its cell size, its
    Δt where its stage takes one, and its particles' stiffness :math:`\rho_p c_p^2` and wave speeds :math:`c_p`, each
    the larger of its material's at rest (:func:`~.states.rest_wave_speeds`) and in its state (a fluid compressed to
    :math:`J = 0.1` is :math:`10^{3.5}` times faster than at rest, and its stress's round-off as much larger)."""
    dt = float(inputs["dt"]) if "dt" in inputs else 0.0
    c = rest_wave_speeds(scene)
    degree = scene.dim * (scene.kernel.support - 1)
    if "material" not in inputs:
        return natural_scales(expected, inputs, scene.grid.dx, None, float(np.max(c)), dt, degree)
    material = np.asarray(inputs["material"])
    particles = particles_from(inputs)
    speeds = np.maximum(c[material], wave_speeds(scene.material_list, particles)) if particles.n else c[material]
    stiffness = np.array([m.rho for m in scene.material_list])[material] * speeds**2
    wave_speed = float(np.max(speeds, initial=np.max(c)))
    return natural_scales(expected, inputs, scene.grid.dx, stiffness, wave_speed, dt, degree)


def _probe_scenes(cases):
    """The distinct scenes of ``cases`` (default: the built-in stress cases), one at a time."""
    seen = set()
    for case in cases if cases is not None else make_cases(stages=("stress",)):
        key = json.dumps(case.scene_dict, sort_keys=True)
        if key not in seen:
            seen.add(key)
            yield case.scene()


def relative_tolerance(value, name="rtol"):
    """A pass threshold on the relative error: a finite number > 0 (at 0 or below, or NaN, no case could pass, and
    an infinite one passes every case), else :class:`~mpmref.errors.ArgumentError` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not (math.isfinite(value) and value > 0):
        raise ArgumentError(name, value, "a finite number > 0 (the pass threshold on the relative error)")
    return float(value)


def check(candidate, cases=None, rtol=None, progress=False, implements=None):
    """Run ``candidate`` on ``cases`` and compare each stage with the reference.

    Parameters
    ----------
    candidate : str, mapping or callable
        What to check; see :func:`stage_functions`. A factory is called once per distinct scene.
    cases : iterable of :class:`~mpmref.conformance.case.ConformanceCase`, optional
        Default: the float64 catalogue of the seven stages of every backend fitted to what the candidate implements,
        :func:`~mpmref.conformance.cases.make_cases` ``(implements=...)``.
    rtol : float, optional
        Pass threshold on each case's relative error (:func:`relative_error`, largest over its outputs), a finite
        number > 0 (:func:`relative_tolerance`). Default: each case's own ``rtol``, 1e-12 in float64.
    progress : bool
        Show a progress bar on standard error, naming the case being run (the first case of each scene
        is where a compiled candidate compiles its kernels, which can take a while).
    implements : :class:`~mpmref.backends.capabilities.Implements`, optional
        What the candidate implements; default: what it declares (:func:`~.candidates.candidate_implements`).

    Returns
    -------
    Report
        :class:`~mpmref.errors.BackendError` instead, before any case, for the GPU backend where no GPU is usable
        (:func:`mpmref.backends.refuse_missing_device`): every case would fail the same way.
    """
    rtol = None if rtol is None else relative_tolerance(rtol)
    found = resolve(candidate)
    refuse_missing_device(found)
    found = validated(found)
    cases = None if cases is None else list(cases)
    if implements is None:
        implements = candidate_implements(found, _probe_scenes(cases))
    if cases is None:
        cases = make_cases(implements=implements)
    runner, results, not_applicable = Candidate(found, implements), [], []
    bar = tqdm(cases, desc="conformance", unit="case", file=sys.stderr, disable=not progress)
    for case in bar:
        bar.set_postfix_str(case.name, refresh=True)
        outcome = runner.run(case, case.rtol if rtol is None else rtol)
        (not_applicable if isinstance(outcome, NotApplicable) else results).append(outcome)
    return Report(results, not_applicable, implements)
