"""The worked solutions of docs/exercises.md run and their predictions hold.

Each ``exercises/solutions/exNN_*.py`` has a ``solve()`` that measures its answer with mpmref and asserts it
against the prediction the exercise asks for; this file runs every one (the few that take seconds are in
the ``slow`` set) and checks that the chapter lists exactly these solutions.
"""

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SOLUTIONS = sorted((ROOT / "exercises" / "solutions").glob("ex[0-9][0-9]_*.py"))
SLOW = {"ex02_largest_stable_cfl", "ex07_wall_friction"}   # several seconds each on two cores


def test_the_chapter_lists_every_solution_once_and_there_are_at_least_eight():
    text = (ROOT / "docs" / "exercises.md").read_text(encoding="utf-8")
    linked = re.findall(r"\[`exercises\.solutions\.(\w+)`\]", text)
    assert sorted(linked) == [p.stem for p in SOLUTIONS]
    assert len(SOLUTIONS) >= 8


@pytest.mark.parametrize("name", [pytest.param(p.stem, marks=[pytest.mark.slow] if p.stem in SLOW else [], id=p.stem)
                                  for p in SOLUTIONS])
def test_worked_solution(name):
    module = importlib.import_module(f"exercises.solutions.{name}")
    assert module.__doc__ and "Prediction" in module.__doc__, "a solution explains its prediction"
    result = module.solve()
    assert result, "solve() returns the numbers it measured"
