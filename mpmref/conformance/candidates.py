"""What a candidate offers the harness: its stage callables for a scene, the stages it lacks (each with the reason a
case of that stage is not applicable), and what it declares it implements.

A candidate is a backend reference of :mod:`mpmref.backends` (a built-in or plugin name, ``"MODULE:ATTRIBUTE"``), a
factory ``factory(scene)`` returning an object with stage methods or a mapping of stage names to callables, or a
mapping of stage names to callables that take the scene first (see :mod:`mpmref.conformance`).
"""

import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import partial

from ..backends.base import BACKEND_STAGES
from ..backends.capabilities import EVERYTHING, declared, probed
from .cpic import CPIC_METHODS, RUNNERS, has_cpic
from .stages import (
    ALL_CONFORMANCE_STAGES,
    ASYNC_CONFORMANCE_STAGES,
    CONFORMANCE_STAGES,
    CPIC_CONFORMANCE_STAGES,
    OPTIONAL_STAGES,
    composed_step,
    ledger_step,
)

#: the keyword argument through which the steppers hand each stage of asynchronous stepping that runs through a plain
#: stage method its extra input: P2G's particle classes, G2P's kicks
ASYNC_KEYWORDS = {"p2g_classes": ("p2g", "classes"), "g2p_kicks": ("g2p", "kicks")}


def _check_stage_names(mapping):
    unknown = sorted(set(mapping) - set(ALL_CONFORMANCE_STAGES))
    if unknown:
        raise TypeError(f"unknown stage names {unknown}: the stages are {list(ALL_CONFORMANCE_STAGES)}")


def accepts_keyword(fn, name):
    """Whether the callable ``fn`` takes a keyword argument ``name`` (by name or through ``**kwargs``)."""
    try:
        parameters = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):  # a builtin without a signature: nothing to check
        return True
    return any(p.name == name or p.kind is p.VAR_KEYWORD for p in parameters)


@dataclass
class StageSet:
    """What a candidate made for one scene: ``functions`` ``{stage: callable}``, ``absent`` ``{stage: reason}`` for
    the stages it lacks, and ``implements``, the declaration of the object it made (everything if none)."""

    functions: dict = field(default_factory=dict)
    absent: dict = field(default_factory=dict)
    implements: object = EVERYTHING


def _lacks(stage):
    kind = "optional stage" if stage in OPTIONAL_STAGES else "stage"
    return f"does not provide the {kind} {stage}"


def _object_stages(obj):
    """The :class:`StageSet` of an object with stage methods.

    An object with the six backend stages (:mod:`mpmref.backends.base`) is also checked on whole steps: its ``step`` is
    the stepper's one pipeline (:func:`mpmref.steppers.substep`) over its stages, and its ``ledger`` that step's
    energy ledger (:func:`.stages.ledger_step`). An object with the CPIC methods (:func:`.cpic.has_cpic`) is also
    checked on the CPIC stages; the stages of asynchronous stepping are its ``wave_speeds`` and ``interface_kicks``,
    and its ``p2g`` and ``g2p`` where they take ``classes`` and ``kicks``.
    """
    out = StageSet(implements=declared(obj))
    for stage in CONFORMANCE_STAGES + ("wave_speeds", "interface_kicks"):
        method = getattr(obj, stage, None)
        if callable(method):
            out.functions[stage] = method
    lacking = [s for s in BACKEND_STAGES if not callable(getattr(obj, s, None))]
    for stage, compose in (("step", composed_step), ("ledger", ledger_step)):
        if stage in out.functions:
            continue
        if lacking:
            out.absent[stage] = f"{_lacks(stage)} (a step composes the six stages; it lacks {', '.join(lacking)})"
        else:
            out.functions[stage] = partial(compose, obj)
    for stage, (name, keyword) in ASYNC_KEYWORDS.items():
        method = getattr(obj, name, None)
        if callable(method) and accepts_keyword(method, keyword):
            out.functions[stage] = method
        elif callable(method):
            out.absent[stage] = f"its {name} takes no {keyword} (asynchronous stepping)"
    if has_cpic(obj):
        out.functions.update({stage: partial(RUNNERS[stage], obj) for stage in CPIC_CONFORMANCE_STAGES})
    else:
        lacking_cpic = [m for m in CPIC_METHODS if not callable(getattr(obj, m, None))]
        out.absent.update({stage: f"does not provide the CPIC methods (it lacks {', '.join(lacking_cpic)})"
                           for stage in CPIC_CONFORMANCE_STAGES})
    for stage in ALL_CONFORMANCE_STAGES:
        if stage not in out.functions and stage not in out.absent:
            words = " (asynchronous stepping)" if stage in ASYNC_CONFORMANCE_STAGES else ""
            out.absent[stage] = _lacks(stage) + words
    return out


def _mapping_stages(mapping, bind=None):
    """The :class:`StageSet` of a mapping of stage names to callables (each given ``bind`` first, if not ``None``)."""
    _check_stage_names(mapping)
    functions = {stage: fn if bind is None else partial(fn, bind) for stage, fn in mapping.items()}
    return StageSet(functions, {stage: _lacks(stage) for stage in ALL_CONFORMANCE_STAGES if stage not in mapping})


def validated(found):
    """``found`` (a resolved candidate) if it is a factory or a mapping of known stage names; :class:`TypeError`
    naming what it is otherwise."""
    if isinstance(found, Mapping):
        _check_stage_names(found)
    elif not callable(found):
        raise TypeError(f"a candidate is a backend reference, a factory(scene) or a mapping of stage callables; got "
                        f"{type(found).__name__} (a backend object is made for one scene: give its factory)")
    return found


def stage_set(found, scene):
    """The :class:`StageSet` of the resolved candidate ``found`` for ``scene`` (a factory is called here; what it
    raises propagates, for the caller to report: :class:`NotImplementedError` declines the scene)."""
    if isinstance(validated(found), Mapping):
        return _mapping_stages(found, scene)
    made = found(scene)
    return _mapping_stages(made) if isinstance(made, Mapping) else _object_stages(made)


def candidate_implements(found, scenes):
    """What the resolved candidate ``found`` declares it implements (:func:`mpmref.backends.capabilities.probed`: a
    factory function that declares nothing is asked through the object it makes for the first of ``scenes`` it can
    make); everything for a mapping of stage callables."""
    return EVERYTHING if isinstance(found, Mapping) else probed(found, scenes)
