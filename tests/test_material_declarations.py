"""Material parameters are declared once, on the material (mpmref.physics.parameters), and the scene validation
is derived from those declarations: its keys, defaults, bounds and messages; docs/scenes.md lists the same."""

import re
from dataclasses import dataclass
from pathlib import Path

import pytest

from mpmref import Scene, SceneError
from mpmref.physics.catalogue import MATERIALS
from mpmref.physics.materials import ElasticSolid
from mpmref.physics.parameters import declared, parameter

ROOT = Path(__file__).resolve().parent.parent
REQUIRED = {"E": 1.0e3, "K": 1.0e3}


def scene_with(material):
    return {"dim": 2, "grid": {"size": 1.0, "cells": 16}, "materials": {"m": material},
            "bodies": [{"shape": "box", "material": "m", "lower": [0.3, 0.3], "upper": [0.6, 0.6]}],
            "time": {"dt": 1.0e-3}}


def minimal(kind):
    """A table of material ``kind`` with only its required parameters."""
    return {"type": kind, **{p.name: REQUIRED[p.name] for p in declared(MATERIALS[kind]) if p.default is None}}


def interval(bounds):
    """The range as the validator and docs/scenes.md write it, e.g. ``(0.0, 1.0]``."""
    lo = "-inf" if bounds.lo is None else bounds.lo
    hi = "inf" if bounds.hi is None else bounds.hi
    return f"{'(' if bounds.lo_open else '['}{lo}, {hi}{')' if bounds.hi_open else ']'}"


def outside(bounds):
    """Values just outside each finite end of the range (the end itself where it is open)."""
    values = []
    if bounds.lo is not None:
        values.append(bounds.lo if bounds.lo_open else bounds.lo - 1e-3)
    if bounds.hi is not None:
        values.append(bounds.hi if bounds.hi_open else bounds.hi + 1e-3)
    return values


CASES = [(kind, p) for kind, cls in MATERIALS.items() for p in declared(cls)]
IDS = [f"{kind}.{p.name}" for kind, p in CASES]


def test_every_material_declares_every_parameter_with_a_range():
    for kind, cls in MATERIALS.items():
        names = [p.name for p in declared(cls)]
        assert names[0] == "rho", kind  # the density is checked first, in every material
        assert names, kind


@pytest.mark.parametrize("kind, p", CASES, ids=IDS)
def test_defaults_come_from_the_declaration(kind, p):
    material = Scene.from_dict(scene_with(minimal(kind))).materials["m"]
    assert type(material) is MATERIALS[kind]
    expected = REQUIRED[p.name] if p.default is None else p.default
    assert getattr(material, p.name) == expected


@pytest.mark.parametrize("kind, p", CASES, ids=IDS)
def test_out_of_range_values_are_refused_with_the_declared_bounds(kind, p):
    for value in outside(p.bounds):
        with pytest.raises(SceneError) as info:
            Scene.from_dict(scene_with({**minimal(kind), p.name: value}))
        assert info.value.field == f"materials.m.{p.name}"
        assert info.value.value == value
        assert info.value.allowed == f"a number in {interval(p.bounds)}"


@pytest.mark.parametrize("kind, p", [(k, p) for k, p in CASES if p.default is None],
                         ids=[i for i, (_, p) in zip(IDS, CASES) if p.default is None])
def test_parameters_without_a_default_are_required(kind, p):
    table = minimal(kind)
    del table[p.name]
    with pytest.raises(SceneError) as info:
        Scene.from_dict(scene_with(table))
    assert info.value.field == f"materials.m.{p.name}"
    assert info.value.allowed == f"a number in {interval(p.bounds)} (required)"


def test_a_material_added_to_the_catalogue_is_validated_from_its_declaration(monkeypatch):
    """Adding a material touches mpmref/physics only: the scene reads its keys, defaults and bounds."""

    @dataclass(frozen=True)
    class Damped(ElasticSolid):
        damping: float = parameter(default=0.25, lo=0.0, hi=1.0, hi_open=True)

    monkeypatch.setitem(MATERIALS, "damped", Damped)
    material = Scene.from_dict(scene_with({"type": "damped", "E": 2.0e3, "rho": 3.0})).materials["m"]
    assert material == Damped(E=2.0e3, rho=3.0, nu=0.3, damping=0.25)
    with pytest.raises(SceneError, match=re.escape("materials.m.damping' = 1.0 is invalid: allowed a number in "
                                                   "[0.0, 1.0)")):
        Scene.from_dict(scene_with({"type": "damped", "E": 2.0e3, "damping": 1.0}))
    with pytest.raises(SceneError) as info:
        Scene.from_dict(scene_with({"type": "damped", "E": 2.0e3, "theta_c": 0.1}))
    assert info.value.allowed == "one of the known keys ['E', 'damping', 'nu', 'rho', 'type']"


def scenes_md_rows():
    """``{key: (default, allowed)}`` of the ``[materials.NAME]`` table of docs/scenes.md."""
    text = (ROOT / "docs" / "scenes.md").read_text(encoding="utf-8")
    table = text.split("## `[materials.NAME]`", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `(\w+)` \| number \| ([^|]+) \| ([^|]+) \|", table, re.MULTILINE)
    return {key: (default.strip(), allowed.strip()) for key, default, allowed in rows}


def test_docs_scene_reference_lists_the_declared_defaults_and_ranges():
    rows = scenes_md_rows()
    for kind, p in CASES:
        default, allowed = rows[p.name]
        if p.default is None:
            assert default.startswith("required"), (kind, p.name, default)
        else:
            assert float(default.strip("`")) == p.default, (kind, p.name, default)
        documented = re.sub(r"(\d+(?:\.\d+)?)", lambda m: str(float(m.group(1))), allowed)
        assert documented == interval(p.bounds), (kind, p.name, allowed)
