"""The cases at the extremes (mpmref/conformance/extremes.py): each family is in the catalogue and the scene cases at
the stages it concerns, its states hold what their notes say, what the harness refuses is left out, an error is judged
particle by particle, case seeds do not depend on a scene's name, and the planted bugs of tests/planted_extremes.py,
which hide from drawn states, are caught every time."""

import copy
import tomllib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from planted_extremes import PLANTED, GradientSignOnFace, QuirkySvd

from mpmref.conformance import check, make_cases, scene_cases
from mpmref.conformance.extremes import EXTREMES, FROM_REST_STEPS, NEAR_SYMMETRIC, edge_gap
from mpmref.conformance.measures import ROW_FLOOR, relative_error, row_relative_error
from mpmref.conformance.report import case_natural_scales, compare_outputs
from mpmref.conformance.states import cfl_number
from mpmref.conformance.strategies import rotation
from mpmref.physics.svd import polar_2d
from mpmref.run.stability import stable_cfl

ROOT = Path(__file__).resolve().parent.parent
EXTREME_CASES = [c for c in make_cases() if c.extreme is not None]


def extreme_cases(stage=None, family=None, cases=EXTREME_CASES):
    return [c for c in cases if (stage is None or c.stage == stage) and (family is None or c.extreme.name == family)]


# ----------------------------------------------------------------------------------------------- the cases
def test_every_family_is_in_the_catalogue_at_the_stages_it_concerns():
    """Each family at each stage it concerns, in 2D and 3D; the stress of every material at each deformation family
    (the near-symmetric one for the solids), both return maps at their yield surfaces, the positions on each kernel."""
    expected = {"stress": {"rest", "near-symmetric-F", "collapse", "large-stiffness"},
                "return_map": {"yield-surface", "collapse"},
                "p2g": {"on-nodes-and-faces", "domain-edge"}, "p2g_fused": {"on-nodes-and-faces", "domain-edge"},
                "g2p": {"on-nodes-and-faces", "domain-edge"}, "grid_update": {"massless-neighbours"},
                "step": {"on-nodes-and-faces", "domain-edge", "cfl-limit", "from-rest", "pushed-from-rest",
                         "large-stiffness"},
                "ledger": {"cfl-limit"}}
    for dim in (2, 3):
        found = {}
        for case in (c for c in EXTREME_CASES if c.dim == dim):
            found.setdefault(case.stage, set()).add(case.extreme.name)
        assert found == expected
        near = {m["type"] for c in extreme_cases("stress", "near-symmetric-F") if c.dim == dim
                for m in c.scene_dict["materials"].values()}
        assert near == {"fixed_corotated", "neo_hookean", "snow", "sand"}
        kernels = {c.scene().kernel.name for c in extreme_cases("g2p", "on-nodes-and-faces") if c.dim == dim}
        assert kernels == {"linear", "quadratic", "cubic"}
    assert set(EXTREMES) == {n for names in expected.values() for n in names}
    assert all(c.name.endswith(c.extreme.name) for c in EXTREME_CASES)


def test_the_scenes_cases_hold_the_extremes_of_their_stages():
    """jelly (a solid under gravity): every family its stages concern; mpm88 (the fluid alone): no near-symmetric F."""
    jelly = Counter(c.extreme.name for c in scene_cases(ROOT / "examples" / "jelly.toml") if c.extreme)
    assert set(jelly) == {"rest", "near-symmetric-F", "collapse", "on-nodes-and-faces", "domain-edge",
                          "massless-neighbours", "cfl-limit", "from-rest", "pushed-from-rest"}
    fluid = {c.extreme.name for c in scene_cases(ROOT / "examples" / "mpm88.toml") if c.extreme}
    assert "near-symmetric-F" not in fluid and "rest" in fluid


def note_rows(case, word):
    inputs, notes = case.inputs(), case.notes()
    return inputs, [p for p, note in enumerate(notes or []) if note and word in note]


def test_the_deformations_hold_what_their_notes_say():
    """A near-symmetric row has |S01| = b of its polar factor (to round-off); F = I rows are exactly I; a collapse row
    has det F = J; every rung of the ladder appears in 2D's fixed-corotated case."""
    case = next(c for c in extreme_cases("stress", "near-symmetric-F") if c.dim == 2 and "fixed" in c.name)
    inputs, rows = note_rows(case, "|S₀₁|")
    _, S = polar_2d(inputs["F"][rows])
    b = np.array([float(case.notes()[p].split("= ")[1]) for p in rows])
    assert np.allclose(np.abs(S[:, 0, 1]), b, rtol=1e-6, atol=1e-15) and set(b) == set(NEAR_SYMMETRIC)
    rest = next(c for c in extreme_cases("stress", "rest") if c.dim == 3 and "fixed" in c.name)
    inputs, rows = note_rows(rest, "F = I")
    assert rows and all(np.array_equal(inputs["F"][p], np.eye(3)) for p in rows)
    collapse = next(c for c in extreme_cases("stress", "collapse") if c.dim == 2 and "fixed" in c.name)
    inputs, rows = note_rows(collapse, "J = ")
    J = np.array([float(collapse.notes()[p].split("= ")[1]) for p in rows])
    assert np.allclose(np.linalg.det(inputs["F"][rows]), J, rtol=1e-6)


def test_the_positions_are_exactly_on_their_lines_and_edges():
    """On an exact grid (a power-of-two cell size, a whole-cell origin) a node row's grid coordinates are whole
    numbers, a face row's one of them, and a domain-edge row sits at the kernel's lowest allowed coordinate (plus the
    linear hat's gap) or just below its highest; every row is one the reference can take (its stencil in the grid)."""
    for case in extreme_cases(family="on-nodes-and-faces") + extreme_cases(family="domain-edge"):
        scene = case.scene()
        grid, kernel = scene.grid, scene.kernel
        assert np.log2(grid.dx) == round(np.log2(grid.dx)) and np.all(grid.origin / grid.dx % 1 == 0)
        inputs, notes = case.inputs(), case.notes()
        xi = (inputs["x"] - grid.origin) / grid.dx
        gap = edge_gap(kernel)
        assert xi.min() >= kernel.low_margin and np.all(xi.max(axis=0) < np.array(grid.cells) - kernel.high_margin)
        for p, note in enumerate(notes):
            if note and "on a node" in note:
                assert np.all(xi[p] % 1 == 0)
            elif note and "lower edge" in note:
                assert kernel.low_margin + gap in xi[p]


def test_the_grid_states_and_the_steps_hold_what_they_say():
    """Every node with mass has only empty neighbours (the nodes of odd index sum are empty, and a neighbour's sum
    differs by one), some nearly empty; Δt at the limit is the scheme's stable CFL number; a from-rest case starts at
    F = I, v = 0 and runs its steps."""
    for case in extreme_cases("grid_update"):
        mass = case.inputs()["grid_mass"]
        parity = np.indices(case.scene().grid.node_shape).reshape(case.dim, -1).sum(axis=0) % 2
        assert np.all(mass[parity == 1] == 0) and (mass[parity == 0] > 0).any()
        full = mass[mass > 0]
        assert full.min() < 1e-9 * full.max()
    for case in extreme_cases("step", "cfl-limit"):
        scene = case.scene()
        assert cfl_number(scene) == pytest.approx(stable_cfl(scene.method.scheme), rel=1e-12)
    for case in extreme_cases("step", "from-rest"):
        inputs = case.inputs()
        assert int(inputs["steps"]) == FROM_REST_STEPS[case.dim]
        assert np.all(inputs["F"] == np.eye(case.dim)) and np.all(inputs["v"] == 0.0)


def test_what_the_extremes_refuse():
    """No inverted Neo-Hookean F (its stress is NaN there), no fluid J below 1e-4 or negative; no position, Δt-limit
    or multi-step case in float32 (there the float32 reference itself lies further than its tolerance from the float64
    one); no Δt at the limit for the linear hat; no position extremes for a PolyPIC scene."""
    neo = next(c for c in extreme_cases("stress", "collapse") if "neo_hookean" in c.name)
    assert not any(n and "inverted" in n for n in neo.notes())
    fluid = next(c for c in extreme_cases("stress", "collapse") if c.name.startswith("stress-2d-fluid"))
    assert fluid.inputs()["J"].min() >= 1e-4
    f32 = {c.extreme.name for c in make_cases(dtype="float32") if c.extreme is not None}
    assert f32 == {"rest", "near-symmetric-F", "collapse", "yield-surface", "massless-neighbours", "large-stiffness"}
    assert not any(c.scene().kernel.name == "linear" for c in extreme_cases(family="cfl-limit"))
    scene = tomllib.loads((ROOT / "examples" / "jelly.toml").read_text())
    scene["method"] = {"scheme": "polypic"}
    assert not {c.extreme.name for c in scene_cases(scene) if c.extreme} & {"on-nodes-and-faces", "domain-edge"}


def test_the_extremes_are_seeded_and_their_seeds_free_of_the_scenes_name():
    """Every case is the same on every call; a scene's cases are the same under another name; another base seed draws
    other states."""
    for case in EXTREME_CASES[::7]:
        first, again = case.inputs(), case.inputs()
        assert all(np.array_equal(first[k], again[k]) for k in first)
    jelly = tomllib.loads((ROOT / "examples" / "jelly.toml").read_text())
    renamed = {**copy.deepcopy(jelly), "name": "something-else"}
    for a, b in zip(scene_cases(jelly), scene_cases(renamed)):
        assert a.name != b.name and all(np.array_equal(a.inputs()[k], b.inputs()[k]) for k in a.inputs())
    other = scene_cases(jelly, stages=("stress",), seed=3)
    assert not np.array_equal(other[0].inputs()["F"], scene_cases(jelly, stages=("stress",))[0].inputs()["F"])


# --------------------------------------------------------------------------------------------- the error
def test_a_particles_error_is_judged_on_its_own_scale_with_a_floor():
    """A particle near rest wrong by a large part of its small stress fails, though the case-wide error (over the
    largest stress) passes; a row at zero is judged against the floor, 0.227 of the largest entry in float64."""
    reference = np.array([[1.0, 2.0], [1e-6, 0.0], [0.0, 0.0]])
    wrong = reference.copy()
    wrong[1, 0] += 1e-10
    assert relative_error(wrong, reference) == pytest.approx(5e-11)
    assert row_relative_error(wrong, reference, ROW_FLOOR["float64"]) == pytest.approx(1e-10 / (0.227 * 2),
                                                                                        rel=1e-2)
    wrong[2, 1] = 1e-13
    assert row_relative_error(wrong, reference, 1.0) == pytest.approx(5e-11)  # a floor of 1 is the case-wide rule
    assert row_relative_error(wrong, reference, 1e-7) == pytest.approx(1e-4)   # each row on its own scale


def test_an_output_theory_puts_at_zero_is_judged_on_its_natural_scale():
    """One fixed-corotated particle whose F is a rotation: its stress is zero in theory and round-off in every code.
    Round-off of its stiffness (100 ulps of k = λ + 2μ) passes, which it could not on the output's own scale; an error
    of 1e-9 k fails (docs/conformance.md, "The error")."""
    case = next(c for c in make_cases(dims=(3,), stages=("stress",), extremes=False)
                if c.materials == {"fixed_corotated"})
    inputs = case.inputs()
    n = len(inputs["x"])
    one = {k: a[:1].copy() if a.ndim and len(a) == n else a for k, a in inputs.items()}
    one["F"][0] = rotation(3, (0.3, -1.1, 0.7))
    expected = case.reference(one)
    material = case.scene().material_list[0]
    k = material.lam + 2.0 * material.mu
    natural = case_natural_scales(case.scene(), one, expected)
    assert np.max(np.abs(expected["tau"])) < 1e-12 * k     # zero in theory
    round_off = {"tau": expected["tau"] + 100 * np.finfo(float).eps * k}
    assert compare_outputs(round_off, expected, natural=natural)[0]["tau"] < 1e-12
    assert compare_outputs(round_off, expected)[0]["tau"] > 1.0  # on its own scale, round-off is all of it
    wrong = {"tau": expected["tau"] + 1e-9 * k}
    assert compare_outputs(wrong, expected, natural=natural)[0]["tau"] > 1e-12


def test_a_failure_names_the_extreme_its_worst_particle_holds():
    """The failure line reads 'stress-2d-fixed_corotated-near-symmetric-F (|S₀₁| = 1e-06 at particle N): tau ...'."""
    case = next(c for c in extreme_cases("stress", "near-symmetric-F") if c.dim == 2 and "fixed" in c.name)
    report = check(QuirkySvd, [case])
    (result,) = report.failures()
    assert "|S₀₁| = " in result.holds and "at particle" in result.holds
    assert f"{case.name} ({result.holds}): tau " in report.table()
    assert float(result.errors["tau"]) >= result.errors["tau"].case_wide


# ------------------------------------------------------------------------------------------ planted bugs
#: each planted bug, the stages it lives in and the scene it is live in (a scene at world zero and beyond for the
#: world-anchored int(); the linear hat for the gradient)
JELLY = tomllib.loads((ROOT / "examples" / "jelly.toml").read_text())
SCENES = {"quirky-svd": JELLY, "int-base-node": {**JELLY, "grid": {**JELLY["grid"], "origin": [-0.5, -0.5]},
                                                 "bodies": [{**JELLY["bodies"][0], "lower": [-0.15, -0.05],
                                                             "upper": [0.15, 0.2]}]},
          "skips-at-yield-surface": str(ROOT / "examples" / "snow88.toml"),
          "gradient-sign-on-face": {**JELLY, "method": {"scheme": "pic", "force": "classic", "kernel": "linear"}}}
STAGES = {"quirky-svd": ("stress", "return_map"), "int-base-node": ("p2g", "g2p"),
          "skips-at-yield-surface": ("return_map",), "gradient-sign-on-face": ("p2g", "g2p", "step")}


@pytest.mark.parametrize("bug", list(PLANTED))
def test_each_planted_bug_is_caught_by_the_catalogues_extremes(bug):
    """The catalogue's 2D cases of the stages the bug lives in fail (the default seed), among them cases at the
    extremes."""
    report = check(PLANTED[bug], make_cases(dims=(2,), stages=STAGES[bug]))
    assert not report.passed
    assert any(r.case.extreme is not None for r in report.failures()), report.table()


@pytest.mark.slow
@pytest.mark.parametrize("bug", list(PLANTED))
def test_each_planted_bug_is_caught_on_every_seed(bug):
    """Seeds 0 to 9: the catalogue (2D and 3D) and the cases of a scene where the bug is live catch it every time."""
    for seed in range(10):
        assert not check(PLANTED[bug], make_cases(stages=STAGES[bug], seed=seed)).passed, (bug, seed)
        stages = [s for s in STAGES[bug] if s != "return_map" or bug != "quirky-svd"]
        assert not check(PLANTED[bug], scene_cases(SCENES[bug], stages=stages, seed=seed)).passed, (bug, seed)


def test_the_gradient_bug_is_invisible_off_the_lines():
    """The planted gradient bug agrees with the reference on every drawn case (no weight of the linear hat is zero
    there): only particles exactly on a node line show it."""
    drawn = [c for c in make_cases(dims=(2,), stages=("p2g", "g2p"), kernels=("linear",)) if c.extreme is None]
    assert check(GradientSignOnFace, drawn).passed
