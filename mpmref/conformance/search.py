"""``mpmref conformance search``: a property-based search for states where a backend and the reference disagree.

The cases of ``conformance check`` are drawn once and fixed; the search draws states until one shows a disagreement
beyond the tolerance, with hypothesis, from strategies biased toward the extremes (:mod:`.strategies`): the rungs
of :mod:`~mpmref.conformance.extremes`, particles on node lines and at the domain's edge, nodes without mass, Δt at
the stability limit.
Hypothesis then *shrinks* what it found to the smallest, simplest state that still shows it (fewest particles, fewest
cells, the first rung of a ladder, round numbers), which is printed and saved as a case file (:mod:`.casefile`) that
``conformance check --case FILE`` reruns and a user's regression tests can keep.

The budget is a number of states (:data:`DEFAULT_BUDGET`) or a time; it is shared out among the stages in rounds of
:data:`ROUND` states each, stage after stage, so that a search cut short has looked at every stage. A search that
finds nothing says how many states it tried, per stage and per region (``F near-symmetric``, ``x on a line``,
``Δt at the stability limit``, ...). A state on which the reference itself is ill-conditioned, whose outputs move
by more than a quarter of the tolerance when its inputs change by a few ulps (:func:`steady`: a sand particle
collapsed to :math:`J = 10^{-8}`, whose stored energy reads its smallest singular value through a logarithm), cannot
be judged at the tolerance: it is counted apart, as the states the reference refuses are, and never reported as a
disagreement. Needs hypothesis (the ``test`` extra: ``pip install -e '.[test]'``), which it
imports when it searches: :func:`search` raises :class:`ImportError` without it.
"""

import itertools
import random
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..backends import refuse_missing_device, resolve
from .candidates import candidate_implements, validated
from .casefile import save_case
from .cases import make_cases
from .diagnosis import compared_rows
from .report import Candidate, CaseResult, Report, case_natural_scales, compare_outputs
from .scenes import load_scene, scene_cases, scene_stages
from .stages import CONFORMANCE_STAGES

#: states a search tries by default, all stages together
DEFAULT_BUDGET = 800
#: states per stage in one round (:func:`search`)
ROUND = 25
#: the stages a search draws states for
SEARCH_STAGES = CONFORMANCE_STAGES
#: the change of a state's inputs, in ulps of their dtype, that probes the reference's own conditioning (:func:`steady`)
PROBE_ULPS = 4
#: how far, as a fraction of the tolerance, that change may move the reference's outputs for the state to be judged
STEADY_FRACTION = 0.25
#: inputs every code reads exactly as given, left unchanged by the probe: the positions (a particle on a node line
#: stays there, where the linear hat's gradient jumps)
EXACT_INPUTS = ("x",)


@dataclass
class Found:
    """A disagreement: the shrunk ``case``, its :class:`~.report.CaseResult`, how many states its stage had tried when
    it showed (``after``), and the file it was saved to (``path``, or ``None``)."""

    case: object
    result: CaseResult
    after: int
    path: Path | None = None


@dataclass
class SearchReport:
    """What a search did: the states it tried per stage (``tried``) and per stage and region (``regions``), what it
    found, the stages it could not search with the reason (``skipped``), and per stage the states the reference
    refused (``refused``) or is ill-conditioned on (``unsteady``, :func:`steady`), which are not judged."""

    tried: Counter = field(default_factory=Counter)
    regions: dict = field(default_factory=dict)
    found: list = field(default_factory=list)
    skipped: dict = field(default_factory=dict)
    seconds: float = 0.0
    refused: Counter = field(default_factory=Counter)
    unsteady: Counter = field(default_factory=Counter)

    @property
    def total(self):
        return sum(self.tried.values())

    def text(self, backend=""):
        """The search's summary: each disagreement (its failure line, the shrunk state, where it is saved) or that
        none was found, then the states tried per stage and region."""
        lines = []
        for f in self.found:
            lines += _found_lines(f, backend)
        for stage, reason in self.skipped.items():
            lines.append(f"not searched: {stage}: {reason}")
        lines.append(f"tried {self.total} states in {self.seconds:.0f} s, by stage and region:")
        for stage, count in self.tried.items():
            regions = ", ".join(f"{name} {n}" for name, n in self.regions.get(stage, Counter()).most_common())
            lines.append(f"  {stage} {count}: {regions}")
        for stage in self.tried:
            if self.refused[stage] or self.unsteady[stage]:
                lines.append(f"  not judged in {stage}: {self.refused[stage]} states the reference refuses, "
                             f"{self.unsteady[stage]} on which it is ill-conditioned")
        verdict = (f"FOUND {len(self.found)} disagreement{'s' if len(self.found) > 1 else ''}" if self.found else
                   f"nothing found: every one of {self.total} states within tolerance")
        lines.append(verdict)
        return "\n".join(lines)


def _found_lines(found, backend):
    """The lines of one disagreement: the case's failure line, its state, the file and the command that replays it."""
    result, case = found.result, found.case
    inputs = case.inputs()
    size = (f"{len(inputs['x'])} particle{'s' if len(inputs['x']) > 1 else ''}" if "x" in inputs
            else f"{len(inputs['grid_mass'])} nodes")
    cells = " x ".join(str(c) for c in case.scene().grid.cells)
    lines = [f"FOUND {case.name} after {found.after} states of its stage, shrunk to {size} in {cells} cells:",
             *_result_lines(result), *state_lines(case, inputs)]
    if found.path is not None:
        lines.append(f"  saved to {found.path}; replay: mpmref conformance check --backend {backend or 'B'} "
                     f"--case {found.path}")
    return lines


def _result_lines(result):
    """The failure lines of ``result`` as the check's table has them."""
    return Report([result]).table().splitlines()[2:-1]


def state_lines(case, inputs, digits=6):
    """The state of a (shrunk) case, one line per particle (its material, what it holds, and its fields) or its nodes
    with mass, and Δt."""
    def short(a):
        return np.array2string(np.asarray(a, dtype=np.float64), precision=digits, separator=", ",
                               suppress_small=False, max_line_width=200).replace("\n", "")

    lines = []
    if "x" in inputs:
        notes = case.notes() or [None] * len(inputs["x"])
        names = list(case.scene().materials)
        for p in range(len(inputs["x"])):
            fields = ", ".join(f"{k} = {short(inputs[k][p])}" for k in ("x", "v", "C", "F", "J", "Jp")
                               if k in inputs)
            lines.append(f"  particle {p} ({names[inputs['material'][p]]}; {notes[p]}): {fields}")
    else:
        full = np.flatnonzero(inputs["grid_mass"] > 0)
        lines.append(f"  {len(full)} of {len(inputs['grid_mass'])} nodes with mass")
    lines += [f"  {k} = {float(inputs[k]):.6g}" for k in ("dt", "time") if k in inputs]
    return lines


def templates(stage, runner, scene=None, seed=0):
    """The cases whose scenes a search of ``stage`` draws states for: the catalogue's (fitted to what the candidate
    implements) or one of the user's ``scene``, without extremes; those the candidate implements and provides."""
    if scene is None:
        cases = make_cases(stages=(stage,), implements=runner.implements, seed=seed, extremes=False)
    else:
        cases = scene_cases(scene, stages=(stage,), count=1, seed=seed, extremes=False)
    return [c for c in cases if applies(runner, c)]


def applies(runner, case):
    """Whether the candidate implements ``case``'s parts and provides its stage."""
    if runner.implements.missing(case.scene(), case.parts):
        return False
    made = runner.stages_for(case)
    return not isinstance(made, tuple) and case.stage in made.functions and not made.implements.missing(
        case.scene(), case.parts)


class _Stage:
    """The search of one stage: its templates (drawn kernel first, then a template of that kernel), its states tried
    and regions, and what it found."""

    def __init__(self, stage, runner, cases, rtol, deadline):
        from hypothesis import strategies as st

        from .strategies import searched_case

        self.stage, self.runner, self.rtol, self.deadline = stage, runner, rtol, deadline
        by_kernel = {}
        for case in cases:  # each kernel as likely as any other, whatever the number of its methods
            by_kernel.setdefault(case.scene().kernel.name, []).append(case)
        groups = list(by_kernel.values())
        self.strategy = st.sampled_from(groups).flatmap(st.sampled_from).flatmap(searched_case)
        self.tried, self.refused, self.unsteady, self.regions, self.found, self.first = 0, 0, 0, Counter(), None, None

    def disagrees(self, example):
        """Whether the candidate's outputs on ``example`` lie beyond the tolerance (a state the reference cannot
        compute, or computes ill-conditioned, is counted apart; after the deadline, drawing stops counting)."""
        case, regions = example
        if self.first is None and time.monotonic() > self.deadline:
            return False
        try:
            outcome = self.runner.run(case, self.tolerance(case))
        except Exception:  # the reference raised on the state (a candidate that raises fails its case instead)
            self.refused += 1
            return False
        self.tried += 1
        self.regions.update(regions)
        failed = isinstance(outcome, CaseResult) and not outcome.passed
        if failed and not steady(case, self.tolerance(case)):
            self.unsteady += 1
            return False
        if failed and self.first is None:
            self.first = self.tried
        return failed

    def round(self, states, rng):
        """Draw up to ``states`` states; on a disagreement, shrink it and keep it as :attr:`found`."""
        from hypothesis import HealthCheck, Phase, find, settings
        from hypothesis.errors import NoSuchExample

        chosen = settings(max_examples=states, database=None, deadline=None, phases=(Phase.generate, Phase.shrink),
                          suppress_health_check=list(HealthCheck))
        try:
            case, _ = find(self.strategy, self.disagrees, settings=chosen, random=rng)
        except NoSuchExample:
            return
        self.found = Found(case, self.runner.run(case, self.tolerance(case)), self.first)

    def tolerance(self, case):
        """The search's tolerance, else the case's own."""
        return case.rtol if self.rtol is None else self.rtol


def steady(case, tolerance, probes=4):
    """Whether the reference's outputs on ``case`` move by at most :data:`STEADY_FRACTION` of ``tolerance`` (judged as
    a candidate's are) when every floating input but :data:`EXACT_INPUTS` changes by :data:`PROBE_ULPS` ulps of its
    dtype (Gaussian, ``probes`` times): a correct code rounds differently by a few ulps, so a state that fails this
    cannot tell a wrong code from a correct one at ``tolerance``."""
    inputs, scene = case.inputs(), case.parsed_scene()
    expected = case.reference(inputs)
    natural, rows = case_natural_scales(scene, inputs, expected), compared_rows(scene, inputs)
    rng = np.random.default_rng(case.seed)
    for _ in range(probes):
        moved, _ = compare_outputs(case.reference(_nudged(inputs, rng)), expected, rows, natural)
        if max(moved.values(), default=0.0) > STEADY_FRACTION * tolerance:
            return False
    return True


def _nudged(inputs, rng):
    """``inputs`` with every floating array but :data:`EXACT_INPUTS` changed by :data:`PROBE_ULPS` ulps (relative)."""
    def nudge(a):
        eps = np.finfo(a.dtype).eps
        return (a * (1.0 + PROBE_ULPS * eps * rng.standard_normal(a.shape))).astype(a.dtype)
    return {k: nudge(a) if k not in EXACT_INPUTS and a.ndim and a.dtype.kind == "f" else a for k, a in inputs.items()}


def search(candidate, scene=None, stages=None, budget=DEFAULT_BUDGET, seconds=None, seed=0, out_dir=None, rtol=None,
           progress=False):
    """Search for states where ``candidate`` and the reference disagree (module docstring).

    Parameters
    ----------
    candidate : str, mapping or callable
        As for :func:`~.report.check`.
    scene : str, pathlib.Path, dict or Scene, optional
        Draw the states in this scene (its method, materials, walls, ...); default: in the catalogue's scenes.
    stages : sequence of str, optional
        The stages to search (default: every stage of :data:`SEARCH_STAGES` the scene's steps call).
    budget : int or None
        States to try, all stages together (:data:`DEFAULT_BUDGET`); ``None``: until ``seconds`` have passed.
    seconds : float, optional
        Stop drawing after this many seconds (a disagreement found by then is still shrunk).
    seed : int
        The base seed (of the templates' scenes and of hypothesis's draws).
    out_dir : str or pathlib.Path, optional
        Where each shrunk disagreement is saved as ``<case name>.npz`` (:func:`.casefile.save_case`); ``None``: not
        saved.
    rtol : float, optional
        The tolerance (default: each case's own, 1e-12 in float64).

    Returns
    -------
    SearchReport
    """
    if budget is None and seconds is None:
        raise ValueError("a search needs a budget of states or a time")
    found = validated(resolve(candidate))
    refuse_missing_device(found)
    start = time.monotonic()
    deadline = start + (seconds if seconds is not None else float("inf"))
    probes = make_cases(stages=("stress",)) if scene is None else scene_cases(scene, stages=("stress",), count=1)
    runner = Candidate(found, candidate_implements(found, (c.scene() for c in probes)))
    report = SearchReport()
    searches = _stage_searches(stages, runner, scene, seed, rtol, deadline, report)
    rng = random.Random(seed)
    rounds = itertools.count() if budget is None else range(max(1, -(-budget // (ROUND * max(1, len(searches))))))
    bar = tqdm(total=None if budget is None else len(rounds) * ROUND * len(searches), desc="search", unit="state",
               file=sys.stderr, disable=not progress)
    for _ in rounds:
        pending = [s for s in searches if s.found is None]
        if not pending or time.monotonic() > deadline:
            break
        for s in pending:
            before = s.tried
            s.round(ROUND, random.Random(rng.getrandbits(64)))
            bar.update(s.tried - before)
    bar.close()
    for s in searches:
        report.tried[s.stage] = s.tried
        report.regions[s.stage] = s.regions
        report.refused[s.stage], report.unsteady[s.stage] = s.refused, s.unsteady
        if s.found is not None:
            if out_dir is not None:
                Path(out_dir).mkdir(parents=True, exist_ok=True)
                s.found.path = save_case(s.found.case, Path(out_dir) / f"{s.found.case.name}.npz",
                                         found={"backend": str(candidate), "after": s.found.after, "seed": seed})
            report.found.append(s.found)
    report.seconds = time.monotonic() - start
    return report


def _stage_searches(stages, runner, scene, seed, rtol, deadline, report):
    """A :class:`_Stage` for each stage to search that has templates; the others in ``report.skipped``."""
    searches = []
    chosen = SEARCH_STAGES if stages is None else stages
    if scene is not None:
        called = scene_stages(load_scene(scene)[1])
        report.skipped.update({s: "the scene's steps do not call it" for s in chosen if s not in called})
        chosen = [s for s in chosen if s in called]
    for stage in chosen:
        cases = templates(stage, runner, scene, seed)
        if cases:
            searches.append(_Stage(stage, runner, cases, rtol, deadline))
        else:
            report.skipped[stage] = "the candidate implements or provides no case of it"
    return searches
