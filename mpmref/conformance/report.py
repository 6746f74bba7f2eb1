"""Run a candidate backend on the conformance cases and compare each stage with the NumPy reference."""

import json
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from tqdm import tqdm

from ..backends import resolve
from ..backends.base import BACKEND_STAGES
from .cases import make_cases
from .cpic import RUNNERS, has_cpic
from .diagnosis import compared_rows, restrict, uniform_ratio, worst_place
from .stages import (
    ALL_CONFORMANCE_STAGES,
    CONFORMANCE_STAGES,
    CPIC_CONFORMANCE_STAGES,
    composed_step,
    ledger_step,
    run_stage,
)


def relative_error(candidate, reference, scale=None):
    r"""Relative error of one output array: :math:`\max|a - r| / \max|r|`, or :math:`\max|a - r| / S` with a given
    ``scale`` :math:`S`.

    The maxima run over every entry of the array. Where the reference is all zero (and no scale is given) the
    denominator is 1, so the error is :math:`\max|a|`. A shape mismatch or a non-finite difference counts as
    ``inf``.
    """
    a, r = np.asarray(candidate), np.asarray(reference)
    if a.shape != r.shape:
        return math.inf
    diff = float(np.max(np.abs(a.astype(np.float64) - r.astype(np.float64)), initial=0.0))
    if scale is None:
        scale = float(np.max(np.abs(r.astype(np.float64)), initial=0.0))
    error = diff / scale if scale > 0.0 else diff
    return error if math.isfinite(error) else math.inf


def output_scale(name, expected):
    """The denominator of output ``name``'s error other than its own largest entry, or ``None``: the reference's
    ``energy_scale`` for a ledger term (``ledger_*``). A term is a difference of energies of that size, so its
    round-off is relative to it, not to the term (which theory may put at zero:
    :func:`mpmref.observe.ledger.energy_scale`)."""
    return float(expected["energy_scale"]) if name.startswith("ledger_") and "energy_scale" in expected else None


def compare_outputs(got, expected, rows=None):
    """Per-output relative errors of ``got`` against ``expected`` and a note on missing or misshapen outputs.

    ``rows`` (:func:`.diagnosis.compared_rows`) restricts ``F``, ``J`` and ``Jp`` to the particles whose material
    evolves them; a misshapen output is compared whole (and fails); a ledger term is compared relative to the
    reference's energy scale (:func:`output_scale`)."""
    rows = rows or {}
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
        errors[name] = relative_error(restrict(name, value, rows), restrict(name, ref, rows),
                                      output_scale(name, expected))
    return errors, "; ".join(problems)


@dataclass(frozen=True)
class CaseResult:
    """The outcome of one case: the relative error of each output, the threshold and any problem met.

    ``error`` is the largest output error (``inf`` when no output could be compared, e.g. the candidate
    raised); the case passes when ``error <= rtol``.
    """

    case: object
    errors: dict
    rtol: float
    note: str = ""
    where: str = ""  # the worst output's worst particle or node (:func:`.diagnosis.worst_place`)
    ratio: float | None = None  # the worst output is this factor times the reference everywhere, if it is

    @property
    def error(self):
        return max(self.errors.values(), default=math.inf)

    @property
    def worst_output(self):
        return max(self.errors, key=self.errors.get, default="")

    @property
    def passed(self):
        return self.error <= self.rtol


@dataclass
class Report:
    """Results of :func:`check`: one :class:`CaseResult` per case run, and the cases whose stage the
    candidate does not provide (``skipped``)."""

    results: list
    skipped: list = field(default_factory=list)

    @property
    def passed(self):
        """True when at least one case ran and every case that ran passed."""
        return bool(self.results) and all(r.passed for r in self.results)

    def failures(self):
        return [r for r in self.results if not r.passed]

    def failed_stages(self):
        return {r.case.stage for r in self.failures()}

    def worst(self):
        """The result furthest from passing (largest ``error / rtol``), or ``None`` if nothing ran."""
        return max(self.results, key=lambda r: r.error / r.rtol, default=None)

    def stage_summary(self):
        """Per stage that ran: ``{stage: (cases, failed, worst CaseResult)}`` in stage order."""
        summary = {}
        for stage in ALL_CONFORMANCE_STAGES:
            rows = [r for r in self.results if r.case.stage == stage]
            if rows:
                worst = max(rows, key=lambda r: r.error / r.rtol)
                summary[stage] = (len(rows), sum(not r.passed for r in rows), worst)
        return summary

    def table(self, verbose=False):
        """A readable text table: one line per stage, then the failed cases (every case if ``verbose``)."""
        lines = [f"{'stage':<12} {'cases':>5} {'failed':>6} {'max rel. error':>14} {'rtol':>8}  worst case (output)"]
        for stage, (count, failed, worst) in self.stage_summary().items():
            lines.append(f"{stage:<12} {count:>5} {failed:>6} {worst.error:>14.3e} {worst.rtol:>8.0e}  "
                         f"{worst.case.name} ({worst.worst_output})")
        skipped = sorted({c.stage for c in self.skipped}, key=ALL_CONFORMANCE_STAGES.index)
        if skipped:
            lines.append(f"not provided by the candidate (skipped): {', '.join(skipped)}")
        rows = self.results if verbose else self.failures()
        if rows:
            lines.append("" if verbose else "failed cases:")
            lines += [_case_line(r) for r in rows]
        lines.append(f"{'PASSED' if self.passed else 'FAILED'}: {len(self.results) - len(self.failures())} of "
                     f"{len(self.results)} cases within tolerance")
        return "\n".join(lines)


def _case_line(result):
    status = "ok  " if result.passed else "FAIL"
    details = [result.note] if result.note else []
    if not result.passed and result.where:
        details.append(f"worst at {result.where}")
    if not result.passed and result.ratio is not None:
        details.append(f"× {result.ratio:.6g} everywhere")
    note = f"  {'; '.join(details)}" if details else ""
    return f"  {status} {result.case.name:<40} {result.worst_output:<14} {result.error:.3e}{note}"


# ------------------------------------------------------------------------------------------ candidates
def _check_stage_names(mapping):
    unknown = sorted(set(mapping) - set(ALL_CONFORMANCE_STAGES))
    if unknown:
        raise TypeError(f"unknown stage names {unknown}: the stages are {list(ALL_CONFORMANCE_STAGES)}")


def _stage_callables(stages):
    """``{stage: callable}`` of an object with stage methods or of a mapping of stage names to callables.

    An object with the six backend stages (:mod:`mpmref.backends.base`) is also checked on whole steps:
    its ``step`` is the stepper's one pipeline (:func:`mpmref.steppers.substep`) over its stages, and its ``ledger``
    that step's energy ledger (:func:`.stages.ledger_step`). An object with the CPIC methods
    (:func:`.cpic.has_cpic`) is also checked on the CPIC stages.
    """
    if isinstance(stages, Mapping):
        _check_stage_names(stages)
        return dict(stages)
    found = {s: getattr(stages, s) for s in CONFORMANCE_STAGES if callable(getattr(stages, s, None))}
    if all(callable(getattr(stages, s, None)) for s in BACKEND_STAGES):
        found.setdefault("step", partial(composed_step, stages))
        found.setdefault("ledger", partial(ledger_step, stages))
    if has_cpic(stages):
        found.update({stage: partial(RUNNERS[stage], stages) for stage in CPIC_CONFORMANCE_STAGES})
    return found


def stage_functions(candidate, scene):
    """The candidate's stage callables for ``scene`` as ``{stage: callable}`` (see :mod:`mpmref.conformance`).

    ``candidate`` is a backend reference of :mod:`mpmref.backends` (a built-in or plugin name, or
    ``"MODULE:ATTRIBUTE"``, resolved to what it names), a factory ``factory(scene)`` returning an object with stage
    methods or a mapping of stage names to callables, or a mapping of stage names to callables that take the
    scene first. Unlike :func:`mpmref.backends.make_backend`, a candidate may lack stages: those are skipped.
    (A backend object is made for one scene, and every case has its own: give its factory.)
    """
    found = resolve(candidate)
    if isinstance(found, Mapping):
        _check_stage_names(found)
        return {stage: partial(fn, scene) for stage, fn in found.items()}
    if callable(found):
        return _stage_callables(found(scene))
    raise TypeError(f"a candidate is a backend reference, a factory(scene) or a mapping of stage callables; got "
                    f"{type(found).__name__} (a backend object is made for one scene: give its factory)")


def _run_case(fn, case, rtol):
    inputs = case.inputs()
    expected = case.reference(inputs)
    try:
        got = run_stage(case.stage, fn, inputs)
    except Exception as exc:  # a candidate that raises is a failed case to report, not a crash of the harness
        return CaseResult(case, {}, rtol, note=f"raised {type(exc).__name__}: {exc}")
    scene = case.scene()
    rows = compared_rows(scene, inputs)
    errors, note = compare_outputs(got, expected, rows)
    result = CaseResult(case, errors, rtol, note)
    worst = result.worst_output
    if result.passed or worst not in got:
        return result
    return CaseResult(case, errors, rtol, note,
                      where=worst_place(worst, got[worst], expected[worst], rows, scene, inputs),
                      ratio=uniform_ratio(worst, got[worst], expected[worst], rows))


def check(candidate, cases=None, rtol=None, progress=False):
    """Run ``candidate`` on ``cases`` (default: every float64 case) and compare each stage with the reference.

    Parameters
    ----------
    candidate : str, mapping or callable
        What to check; see :func:`stage_functions`. A factory is called once per distinct scene.
    cases : iterable of :class:`~mpmref.conformance.cases.ConformanceCase`, optional
        Default :func:`~mpmref.conformance.cases.make_cases` ``()``.
    rtol : float, optional
        Pass threshold on each case's relative error (:func:`relative_error`, largest over its outputs).
        Default: each case's own ``rtol``, 1e-12 in float64.
    progress : bool
        Show a progress bar on standard error, naming the case being run (the first case of each scene
        is where a compiled candidate compiles its kernels, which can take a while).

    Returns
    -------
    Report
    """
    cases = make_cases() if cases is None else list(cases)
    built, results, skipped = {}, [], []
    bar = tqdm(cases, desc="conformance", unit="case", file=sys.stderr, disable=not progress)
    for case in bar:
        bar.set_postfix_str(case.name, refresh=True)
        key = json.dumps(case.scene_dict, sort_keys=True)
        if key not in built:
            built[key] = stage_functions(candidate, case.scene())
        fn = built[key].get(case.stage)
        if fn is None:
            skipped.append(case)
        else:
            results.append(_run_case(fn, case, case.rtol if rtol is None else rtol))
    return Report(results, skipped)
