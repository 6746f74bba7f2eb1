"""The verification cases by name, imported lazily, and one way to run any of them.

A case module declares its :class:`~verification.framework.case.VerificationCase` as ``CASE``: ``Params``,
``run(params, backend="numpy", executor=None)``, ``checks(result) -> [Check]``, ``report(result, out_dir)``
and the optional members, each with its default. A case's runs that the backend cannot do are listed in its result
(``result["not_applicable"]``, :mod:`~verification.framework.applicable`); a case none of whose runs applies raises
:class:`~verification.framework.applicable.NothingApplicable` and is *not applicable*, never an error.
"""

import importlib
import importlib.util
import time
import traceback
from dataclasses import dataclass, field

from .applicable import NothingApplicable
from .common import failed
from .failure import locate

#: case name -> module; imported only when the case is run
CASES = {
    "momentum": "verification.momentum",
    "energy": "verification.energy",
    "energy_ledger": "verification.energy_ledger",
    "transfer_energy": "verification.transfer_energy",
    "convergence": "verification.convergence",
    "extremes": "verification.extremes",
    "backends": "verification.backends",
    "speed_accuracy": "verification.speed_accuracy",
    "sync_vs_async": "verification.sync_vs_async",
    "cpic": "verification.cpic",
}


def available():
    """Names of the registered cases whose module is present, in registration order."""
    return [name for name, module in CASES.items() if importlib.util.find_spec(module) is not None]


def load(name):
    """The :class:`~verification.framework.case.VerificationCase` of case ``name`` (its module's ``CASE``); ``KeyError``
    names the available cases."""
    if name not in CASES:
        raise KeyError(f"unknown verification case {name!r}; available: {', '.join(available())}")
    return importlib.import_module(CASES[name]).CASE


@dataclass
class Outcome:
    """What running one case gave: its checks, what was not applicable and what was adapted to the backend, timing,
    and the error if it stopped (its traceback in ``error``; in ``error_line``, one line naming the scene and the
    stage where it was raised, :mod:`~verification.framework.failure`)."""

    name: str
    title: str
    preset: str
    backend: str
    params: object = None
    result: object = None
    checks: list = field(default_factory=list)
    wall_s: float = 0.0
    error: str | None = None
    started: float = 0.0  # epoch seconds: the report lists only files written since
    not_applicable: list = field(default_factory=list)  # NotApplicable items
    adapted: list = field(default_factory=list)  # Adaptation items
    error_line: str | None = None
    case: object = None  # the VerificationCase run (a --scene check is not in the registry)

    @property
    def applicable(self):
        """False when nothing of the case applies to the backend: it ran no check and lists what is not applicable."""
        return bool(self.checks) or not self.not_applicable

    @property
    def passed(self):
        """True when the case ran and has checks, all of which pass."""
        return self.error is None and bool(self.checks) and all(c.passed for c in self.checks)

    @property
    def ok(self):
        """True when nothing failed: every check passes (or none applies) and the case stopped with no error."""
        return self.error is None and (self.passed or not self.applicable)

    @property
    def verdict(self):
        if self.error is not None:
            return "ERROR"
        if not self.applicable:
            return "not applicable"
        n_failed = len(failed(self.checks))
        verdict = "pass" if self.passed else f"FAIL ({n_failed} of {len(self.checks)})"
        return verdict + (f"; {len(self.not_applicable)} not applicable" if self.not_applicable else "")


def run_case(name, preset="quick", backend="numpy", executor=None, out_dir=None, params=None, case=None):
    """Run case ``name`` (``case``: a :class:`~verification.framework.case.VerificationCase` given directly, a check of
    ``mpmref verify --scene``) and evaluate its checks; with ``out_dir`` also write its report files.

    An exception inside the case is caught and kept (with its traceback) in ``Outcome.error``, its place in
    ``Outcome.error_line``, so that a long verification run still reports every other case; such a case counts as
    failed. A case that raises :class:`~verification.framework.applicable.NothingApplicable` is not applicable.
    """
    case = load(name) if case is None else case
    params = case.params(preset) if params is None else params
    outcome = Outcome(name=name, title=case.title, preset=preset, backend=backend, params=params,
                      started=time.time(), case=case)
    start = time.perf_counter()
    try:
        outcome.result = case.run(params, backend=backend, executor=executor)
        outcome.params = ran_with(outcome.result, params)
        outcome.checks = list(case.checks(outcome.result))
        outcome.not_applicable, outcome.adapted = list(listed(outcome.result, "not_applicable")), \
            list(listed(outcome.result, "adapted"))
        if out_dir is not None:
            case.report(outcome.result, out_dir)
    except NothingApplicable as nothing:
        outcome.not_applicable = list(nothing.items)
    except Exception as exc:  # reported in the case's report.md and the index; the case fails
        where = locate(exc)
        outcome.error = traceback.format_exc()
        outcome.error_line = f"{where.text()}: {type(exc).__name__}: " + " ".join(str(exc).split())
    outcome.wall_s = time.perf_counter() - start
    return outcome


def ran_with(result, params):
    """The parameters the case ran with, as its result says (``result["params"]``, where a case fills in what it chose:
    the backends case's candidate), else ``params``."""
    ran = result.get("params") if isinstance(result, dict) else getattr(result, "params", None)
    return params if ran is None else ran


def listed(result, key):
    """The items a case's result lists under ``key`` (``"not_applicable"`` or ``"adapted"``), or none."""
    if isinstance(result, dict):
        return result.get(key, ())
    return getattr(result, key, ())
