"""The contract of a verification case: what ``mpmref verify`` runs, judges and reports.

A case module under ``verification/`` declares one :class:`VerificationCase`, named ``CASE``, from its functions; the
registry (:mod:`verification.framework.registry`) maps the case's name to its module and reads ``CASE`` when the case
runs. Four members are required (``Params``, ``run``, ``checks``, ``report``); every other member has a
default that says what a case without it means, so the framework calls each member directly.

A case runs on what the backend implements: it builds every scene through
:func:`verification.framework.applicable.fit` (or a :class:`~verification.framework.applicable.Triage`), and its
result lists what did not apply under ``"not_applicable"`` and what it adapted under ``"adapted"``; a case none of
whose runs applies raises :class:`~verification.framework.applicable.NothingApplicable`.
"""

from collections.abc import Callable
from dataclasses import dataclass

#: the presets every case has: ``Params.quick()``, ``Params()`` and ``Params.full()``
PRESETS = ("quick", "default", "full")


def no_findings(result):
    """The default ``findings``: the case reports nothing beyond its checks."""
    return ()


def backend_asked(result, backend):
    """The default ``backends_run``: the case ran the backend it was asked for."""
    return (backend,)


def no_tables(result):
    """The default ``tables``: the case has no table for ``results.json`` beyond its checks and findings."""
    return {}


def no_compiled_scenes(params, backend):
    """The default ``compiled_scenes``: the case compiles nothing ahead (:mod:`verification.framework.warmup`)."""
    return []


@dataclass(frozen=True)
class VerificationCase:
    """One verification case.

    Attributes
    ----------
    doc : str
        The case module's docstring; its first line is the case's title.
    Params : class
        A frozen dataclass whose defaults are the standard preset, with the classmethods ``quick()`` and
        ``full()``.
    run : callable
        ``run(params, backend="numpy", executor=None) -> result``: every simulation of the case, its
        independent runs through ``executor`` (a :class:`~verification.framework.executor.Executor`; ``None``: in this
        process).
    checks : callable
        ``checks(result) -> [Check]``: each figure held to a bound (:class:`~verification.framework.common.Check`).
    report : callable
        ``report(result, out_dir)``: the case's plots (saved with
        :func:`~verification.framework.report.save_figure`), VTK series and tables under ``out_dir``.
    findings : callable
        ``findings(result) -> [Finding]``: measured behaviour reported, not judged
        (:class:`~verification.framework.common.Finding`). Default: none.
    backends_run : callable
        ``backends_run(result, backend) -> [str]``: the backends the case ran when asked for ``backend``, for
        the cases that compare backends. Default: ``(backend,)``.
    compiled_scenes : callable
        ``compiled_scenes(params, backend) -> [(backend name, scene)]``: the scenes the case runs on a compiled
        backend, which the warm-up compiles ahead (:mod:`verification.framework.warmup`). Default: none.
    tables : callable
        ``tables(result) -> {name: [row, ...]}``: measured figures the case tabulates for programs, each row a
        dict of column name to a number or a string; ``results.json`` carries them under the case. Default: none.
    main_figure : str or None
        The file name (in the case's folder) of the figure that carries the case's main claim, the one
        ``index.html`` shows. Default ``None``: its first figure.
    runs_alone : bool
        Whether the case times its runs, and so starts only once the whole warm-up is done. Default ``False``.
    """

    doc: str
    Params: type
    run: Callable
    checks: Callable
    report: Callable
    findings: Callable = no_findings
    backends_run: Callable = backend_asked
    compiled_scenes: Callable = no_compiled_scenes
    tables: Callable = no_tables
    main_figure: str | None = None
    runs_alone: bool = False

    @property
    def title(self):
        """The first line of the case's docstring."""
        return self.doc.strip().splitlines()[0]

    def params(self, preset):
        """The parameters of ``preset``: ``Params()`` for ``"default"``, else ``Params.quick()`` /
        ``Params.full()``."""
        if preset not in PRESETS:
            raise ValueError(f"unknown preset {preset!r}; choose one of {PRESETS}")
        return {"quick": self.Params.quick, "default": self.Params, "full": self.Params.full}[preset]()

