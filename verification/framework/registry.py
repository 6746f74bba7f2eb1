"""The verification cases by name, imported lazily, and one way to run any of them.

A case module declares its :class:`~verification.framework.case.VerificationCase` as ``CASE``: ``Params``,
``run(params, backend="numpy", executor=None)``, ``checks(result) -> [Check]``, ``report(result, out_dir)``
and the optional members, each with its default.
"""

import importlib
import importlib.util
import time
import traceback
from dataclasses import dataclass, field

from .common import failed

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
    """What running one case gave: its checks, timing, and the error if it stopped."""

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

    @property
    def passed(self):
        """True when the case ran and has checks, all of which pass."""
        return self.error is None and bool(self.checks) and all(c.passed for c in self.checks)

    @property
    def verdict(self):
        if self.error is not None:
            return "ERROR"
        n_failed = len(failed(self.checks))
        return "pass" if self.passed else f"FAIL ({n_failed} of {len(self.checks)})"


def run_case(name, preset="quick", backend="numpy", executor=None, out_dir=None, params=None):
    """Run case ``name`` and evaluate its checks; with ``out_dir`` also write its report files.

    An exception inside the case is caught and kept (with its traceback) in ``Outcome.error`` so that a
    long verification run still reports every other case; such a case counts as failed.
    """
    case = load(name)
    params = case.params(preset) if params is None else params
    outcome = Outcome(name=name, title=case.title, preset=preset, backend=backend, params=params,
                      started=time.time())
    start = time.perf_counter()
    try:
        outcome.result = case.run(params, backend=backend, executor=executor)
        outcome.checks = list(case.checks(outcome.result))
        if out_dir is not None:
            case.report(outcome.result, out_dir)
    except Exception:  # reported in the case's report.md and the index; the case fails
        outcome.error = traceback.format_exc()
    outcome.wall_s = time.perf_counter() - start
    return outcome
