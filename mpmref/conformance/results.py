"""Stage outputs that another language computed from ``conformance export``'s vectors, checked as a Python backend is
(``mpmref conformance check --results DIR``).

A code outside Python's reach reads the exported cases (``mpmref conformance export VECTORS``), runs its stages on the
``in_`` arrays and writes, into a folder ``DIR`` of its own:

* ``DIR/<case name>.npz``: for every case it computes, its outputs under the names of the exported file's ``out_``
  arrays (``out_grid_mass``, ``out_x``, ...; docs/conformance.md, "Layout of a case file"), same shapes;
* ``DIR/implements.json`` (optional): what it implements, ``{"implements": {...}, "stages": [...]}``, the fields of
  :class:`~mpmref.backends.capabilities.Implements` (``dims``, ``schemes``, ``materials``, ...) and the stages it
  provides; without the file, everything and every stage.

:func:`check_results` gives the same :class:`~.report.Report` a Python backend gets: a case the declaration does not
cover is not applicable with the same reasons (its parts missing, or "does not provide the stage ..."), every other is
compared with the reference by the same error, rows, diagnosis and setting. A case the declaration covers whose file
is missing, unreadable, or lacks an output or has it in another shape is refused before any comparison
(:class:`ResultsError`, naming the case, the file and the field).
"""

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..backends.capabilities import EVERYTHING, EVOLVED, Implements
from ..errors import MpmrefError
from .diagnosis import compared_rows, uniform_ratio, worst_place
from .report import (
    CaseResult,
    NotApplicable,
    Report,
    case_natural_scales,
    compare_outputs,
    describe_setting,
    relative_tolerance,
)
from .stages import ALL_CONFORMANCE_STAGES, OPTIONAL_STAGES

DECLARATION = "implements.json"
#: problems listed when results are refused
LISTED = 10


class ResultsError(MpmrefError, ValueError):
    """Results that cannot be compared: each of ``problems`` names the case, the file and the field."""

    def __init__(self, folder, problems):
        self.folder, self.problems = str(folder), list(problems)
        more = f" (and {len(problems) - LISTED} more)" if len(problems) > LISTED else ""
        super().__init__(f"results in {folder}: {len(problems)} problem{'s' if len(problems) > 1 else ''}{more}: "
                         + "; ".join(self.problems[:LISTED]))


@dataclass(frozen=True)
class Declaration:
    """What the code that wrote the results implements and the stages it provides."""

    implements: Implements = EVERYTHING
    stages: tuple = ALL_CONFORMANCE_STAGES


def read_declaration(path):
    """The :class:`Declaration` of ``path``: a results folder (its ``implements.json``, everything if it has none) or
    the file itself; :class:`ResultsError` naming the field that is wrong."""
    path = Path(path)
    file = path / DECLARATION if path.is_dir() else path
    if not file.exists():
        if path.is_dir():
            return Declaration()
        raise ResultsError(path, [f"{file} does not exist"])
    try:
        data = json.loads(file.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ResultsError(path, [f"{file.name} cannot be read as JSON ({exc})"]) from None
    if not isinstance(data, dict) or set(data) - {"implements", "stages"}:
        raise ResultsError(path, [f"{file.name} must be an object with the keys 'implements' and 'stages'"])
    stages = tuple(data.get("stages", ALL_CONFORMANCE_STAGES))
    unknown = sorted(set(stages) - set(ALL_CONFORMANCE_STAGES))
    if unknown:
        raise ResultsError(path, [f"{file.name} field 'stages': unknown {unknown}; allowed "
                                  f"{list(ALL_CONFORMANCE_STAGES)}"])
    try:
        implements = Implements(**data.get("implements", {}))
    except (TypeError, ValueError) as exc:
        raise ResultsError(path, [f"{file.name} field 'implements': {exc}"]) from None
    return Declaration(implements, stages)


def not_provided(stage):
    """The reason a case of ``stage`` is not applicable to a code that does not provide it (the words the harness
    gives a Python backend without that stage)."""
    kind = "optional stage" if stage in OPTIONAL_STAGES else "stage"
    return f"does not provide the {kind} {stage}"


def applicability(declaration, case, scene):
    """The :class:`~.report.NotApplicable` of ``case`` for the declared code, or ``None`` when it applies."""
    reasons = declaration.implements.missing(scene, case.parts)
    if reasons:
        return NotApplicable(case, tuple(reasons), "declared")
    if case.stage not in declaration.stages:
        return NotApplicable(case, (not_provided(case.stage),), "not provided")
    return None


def read_outputs(folder, case, expected):
    """``(outputs, problems)``: the arrays of ``folder/<case>.npz`` that ``expected`` names, and what is wrong with the
    file (each problem naming the case, the file and the field)."""
    path = Path(folder) / f"{case.name}.npz"
    where = f"case {case.name} ({path.name})"
    if not path.is_file():
        return {}, [f"{where}: no results file"]
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except Exception as exc:  # whatever NumPy raises, the file cannot be read
        return {}, [f"{where}: cannot be read ({type(exc).__name__}: {exc})"]
    outputs, problems = {}, []
    for name, reference in expected.items():
        value = arrays.get(f"out_{name}")
        if value is None:
            problems.append(f"{where}: no field out_{name}")
        elif value.shape != np.shape(reference) or value.dtype.kind not in "fiub":
            problems.append(f"{where}: field out_{name} is {value.dtype.name} {value.shape}, expected numbers of "
                            f"shape {np.shape(reference)}")
        else:
            outputs[name] = value
    return outputs, problems


def compared(case, scene, inputs, expected, got, rtol):
    """The :class:`~.report.CaseResult` of ``got`` against ``expected``, with the diagnosis a Python backend's failed
    case gets (worst place, uniform ratio, setting)."""
    rows = compared_rows(scene, inputs)
    errors, note = compare_outputs(got, expected, rows, case_natural_scales(scene, inputs, expected))
    setting = describe_setting(case, scene, inputs)
    result = CaseResult(case, errors, rtol, note, setting=setting)
    worst = result.worst_output
    if result.passed or worst not in got:
        return result
    where = worst_place(worst, got[worst], expected[worst], rows, scene, inputs)
    ratio = uniform_ratio(worst, got[worst], expected[worst], rows)
    return CaseResult(case, errors, rtol, note, where=where, ratio=ratio, setting=setting)


def check_results(folder, cases, rtol=None, progress=False):
    """Compare the results another code wrote into ``folder`` (module docstring) on ``cases`` with the reference.

    Parameters
    ----------
    folder : str or pathlib.Path
        The code's results: ``<case name>.npz`` files and, optionally, ``implements.json``.
    cases : iterable of :class:`~mpmref.conformance.case.ConformanceCase`
        The cases it was given (``conformance export``'s selection, fitted to its declaration as ``check`` fits the
        catalogue to a backend's: :func:`~mpmref.conformance.cases.make_cases` ``(implements=...)``).
    rtol : float, optional
        Pass threshold (default: each case's own).
    progress : bool
        A progress bar on standard error.

    Returns
    -------
    Report
        :class:`ResultsError` instead, before any comparison, when a case the code implements has no usable results.
    """
    rtol = None if rtol is None else relative_tolerance(rtol)
    declaration = read_declaration(folder)
    evolves = set(declaration.implements.evolves)
    pending, not_applicable, problems = [], [], []
    for case in tqdm(list(cases), desc="results", unit="case", file=sys.stderr, disable=not progress):
        scene = case.scene()
        outcome = applicability(declaration, case, scene)
        if outcome is not None:
            not_applicable.append(outcome)
            continue
        inputs = case.inputs()
        expected = {k: v for k, v in case.reference(inputs).items() if k not in EVOLVED or k in evolves}
        got, found = read_outputs(folder, case, expected)
        problems += found
        pending.append((case, scene, inputs, expected, got))
    if problems:
        raise ResultsError(folder, problems)
    results = [compared(case, scene, inputs, expected, got, case.rtol if rtol is None else rtol)
               for case, scene, inputs, expected, got in pending]
    return Report(results, not_applicable, declaration.implements)
