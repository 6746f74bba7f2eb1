"""What a conformance check compared, and what it never did: the lines ``mpmref conformance check`` prints under its
table, so that a verdict of passed cases does not read as a check of stages no case reached.

A stage the candidate provides may still be compared on no case: every case of it needs a part the candidate does
not declare (a plastic material for ``return_map``, rigid bodies for the CPIC stages), or asks for a method that
mpmref itself cannot model. The first is what the candidate declared; the second is a limit of mpmref, and the
candidate is told so (:func:`mpmref.backends.fitting.unmodelable`): a declaration of APIC with the linear kernel
passes its stress cases, and its P2G, G2P and steps are never compared, because mpmref has no such method to compare
them with.
"""

from ..backends.fitting import unmodelable
from ..physics.catalogue import MATERIALS
from .case import STAGE_PARTS
from .stages import ALL_CONFORMANCE_STAGES, ASYNC_CONFORMANCE_STAGES, CPIC_CONFORMANCE_STAGES


def compared_stages(report):
    """``{stage: cases compared}`` of the stages on which at least one case ran, in stage order."""
    counts = {}
    for result in report.results:
        counts[result.case.stage] = counts.get(result.case.stage, 0) + 1
    return {stage: counts[stage] for stage in ALL_CONFORMANCE_STAGES if stage in counts}


def claims(implements, stage):
    """Whether ``implements`` claims what ``stage`` exists for: asynchronous stepping for the asynchronous stages,
    rigid bodies for the CPIC stages, a plastic material for the return map; every other stage, always."""
    if implements is None:
        return True
    if stage in ASYNC_CONFORMANCE_STAGES:
        return "async" in implements.stepping
    if stage in CPIC_CONFORMANCE_STAGES:
        return bool(implements.rigid_bodies)
    if stage == "return_map":
        return any(MATERIALS[name].plastic for name in implements.materials if name in MATERIALS)
    return True


def never_compared(report):
    """``{stage: its most frequent reason}`` of the stages that had cases, none of which ran, though the candidate
    provides the stage and claims what it exists for (:func:`claims`; its cases are not applicable by what it
    declares or declines, not because it lacks the stage), in stage order."""
    ran = compared_stages(report)
    reasons = {}
    for item in report.not_applicable:
        stage = item.case.stage
        if stage not in ran and item.kind != "not provided" and claims(report.implements, stage):
            for reason in item.reasons:
                reasons.setdefault(stage, {}).setdefault(reason, 0)
                reasons[stage][reason] += 1
    return {stage: max(reasons[stage], key=reasons[stage].get) for stage in ALL_CONFORMANCE_STAGES
            if stage in reasons}


def coverage_lines(report):
    """The lines under the table: the stages compared (with their case counts), the stages provided and claimed
    but never compared (:func:`never_compared`, with the reason of most of their cases), and, for a declaration
    with methods mpmref cannot model, a warning that names them and the stages they leave unchecked (``[]`` when
    nothing ran at all: the verdict says so)."""
    ran = compared_stages(report)
    if not ran:
        return []
    lines = ["compared: " + ", ".join(f"{stage} ({n})" for stage, n in ran.items())]
    missed = never_compared(report)
    lacking = unmodelable(report.implements) if report.implements is not None else []
    method_stages = [stage for stage in missed if lacking and "method" in STAGE_PARTS[stage]]
    missed.update(dict.fromkeys(method_stages, "a declared method mpmref cannot model"))
    if missed:
        lines.append("never compared, though provided: "
                     + "; ".join(f"{stage} ({reason})" for stage, reason in missed.items()))
    if method_stages:
        lines.append(f"warning: {'; '.join(lacking)}: {', '.join(method_stages)} cannot be checked on that part of "
                     "the declaration")
    return lines
