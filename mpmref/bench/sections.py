"""The sections of ``mpmref bench``, registered once.

Each :class:`Section` names what runs it and what renders its table; the ``--only`` choices, the sections a
plain run runs, the runner (:func:`mpmref.bench.run_bench`), the keys of the JSON document and the printed
tables all derive from :data:`SECTIONS`. A new section is one entry there (and its keys in the JSON
description of :mod:`mpmref.bench`).
"""

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .asynchronous import plot_async, render_async, run_async
from .busy import render_busy, run_busy
from .compile_census import render_census, run_census
from .cpic import render_cpic, run_cpic
from .domain import render_domain, run_domain
from .gpu import render_cuda, run_cuda
from .ledger import render_ledger, run_ledger
from .peer import run_peer
from .report import render_peer, render_table2, render_throughput
from .scenes import peer_cases, throughput_cases
from .stage_times import plot_scaling, render_scaling, render_stages, run_scaling, run_stages
from .startup import render_startup, run_startup
from .table2 import run_table2
from .throughput import run_throughput


@dataclass(frozen=True)
class Section:
    """One section of ``mpmref bench``.

    Attributes
    ----------
    name : str
        Its ``--only`` choice and its key in the JSON document.
    run : callable
        ``run(options, log) -> dict``: the section's part of the JSON document, measured with the
        :class:`~mpmref.bench.BenchOptions` ``options``; ``log`` gets a line per measurement being started.
    render : callable
        ``render(section) -> str``: the section's table, from its part of the JSON document.
    default : bool
        Whether a run without ``--only`` runs it (``peer`` runs with ``--vs taichi``).
    """

    name: str
    run: Callable
    render: Callable
    default: bool = True


def _table2(o, log):
    return run_table2(o.table2_cells, o.backends, o.threads, o.dtypes, o.repeats, o.memory, log)


def _table2_2d(o, log):
    return run_table2(o.table2_2d_cells, o.backends, o.threads, o.dtypes, o.repeats, False, log, dim=2)


def _throughput(o, log):
    return run_throughput(throughput_cases(o.quick), o.backends, o.threads, o.dtypes, o.repeats, o.steps, log)


def _stages(o, log):
    return run_stages(throughput_cases(o.quick), o.backends, o.threads, o.dtypes, o.steps, log)


def _scaling(o, log):
    section = run_scaling(o.backends, o.threads, o.dtypes, o.repeats, o.steps, o.full, o.quick, log)
    if o.plot:
        plot_scaling(section, o.plot)
    return section


def _domain(o, log):
    return run_domain(o.backends, o.threads, o.dtypes, o.repeats, o.steps, o.quick, o.memory, log)


def _peer(o, log):
    return run_peer(peer_cases(o.quick), o.backends, o.threads, o.repeats, o.peer_steps, log)


def _async(o, log):
    section = run_async(o.quick, o.backends, o.threads, o.repeats, log, full=o.full)
    if o.plot:  # the plot's own name when the section runs alone, else beside the scaling plot
        path = Path(o.plot)
        plot_async(section, path if o.sections == ("async",) else path.with_name(f"{path.stem}_async{path.suffix}"))
    return section


def _busy(o, log):
    return run_busy(o.quick, o.backends, o.repeats, log)


def _cpic(o, log):
    return run_cpic(o.quick, o.backends, o.threads, o.repeats, o.steps, log)


def _ledger(o, log):
    return run_ledger(o.quick, o.backends, o.threads, o.repeats, o.steps, log)


def _compile(o, log):
    return run_census(log)


def _startup(o, log):
    return run_startup(o.against, o.repeats, log)


#: every section, in the order of the JSON document, of ``--only``'s choices and of a run
SECTIONS = (
    Section("table2", _table2, render_table2),
    Section("table2_2d", _table2_2d, render_table2),
    Section("throughput", _throughput, render_throughput),
    Section("stages", _stages, render_stages),
    Section("scaling", _scaling, render_scaling),
    Section("domain", _domain, render_domain),
    Section("peer", _peer, render_peer, default=False),
    Section("async", _async, render_async, default=False),
    Section("cpic", _cpic, render_cpic),
    Section("busy", _busy, render_busy),
    Section("ledger", _ledger, render_ledger),
    Section("cuda", run_cuda, render_cuda, default=False),
    Section("startup", _startup, render_startup, default=False),
    Section("compile", _compile, render_census, default=False),
)

#: the sections by name
BY_NAME = {section.name: section for section in SECTIONS}
#: the names of every section
NAMES = tuple(BY_NAME)
#: the names of the sections a run without ``--only`` runs
DEFAULT_NAMES = tuple(section.name for section in SECTIONS if section.default)
