"""The conformance harness (mpmref.conformance): its cases cover every combination, every backend passes it,
it catches a broken backend at the stage that is broken, and its exported vectors are the reference's."""

import argparse
import json
import math

import numpy as np
import pytest
from helpers import valid_methods

from mpmref.backends import BACKENDS
from mpmref.backends.numpy import NumpyBackend
from mpmref.conformance import (
    ASYNC_CONFORMANCE_STAGES,
    CONFORMANCE_STAGES,
    ConformanceCase,
    add_parser,
    check,
    export,
    load_vectors,
    make_cases,
    relative_error,
)
from mpmref.conformance.cases import CFL_RANGE, DEFAULT_RTOL, EDGE_CELLS, MIN_WEIGHT, cfl_number
from mpmref.conformance.measures import ROW_FLOOR
from mpmref.conformance.report import case_natural_scales, compare_outputs
from mpmref.conformance.stages import STAGES_WITH_DT, particles_from
from mpmref.physics.kernels import compute_stencil
from mpmref.scene import COLLIDER_SHAPES, MATERIAL_TYPES, WALL_TYPES, Scene
from mpmref.state import GridState

ALL_CASES = make_cases()
#: the drawn cases, without the extremes (tests/test_extremes.py has those)
DRAWN_CASES = [c for c in ALL_CASES if c.extreme is None]
PLANE_CASES = [c for c in DRAWN_CASES if c.dim == 2]  # enough to locate a broken stage, at half the cost
#: the cases of the stages asynchronous stepping adds
ASYNC_CASES = make_cases(stages=ASYNC_CONFORMANCE_STAGES)


def cases_of(stage, cases=ALL_CASES):
    return [c for c in cases if c.stage == stage]


# -------------------------------------------------------------------------------------------- the cases
def test_cases_cover_every_valid_combination():
    """Transfers, steps and ledgers: all 20 valid methods per dimension and APIC with the other force's velocity
    gradient (the force/F-update ablation); stress, steps and ledgers: every material type; grid update: every wall
    type and every collider shape (2D has no cylinder); the ledger: the colliders too (where ``boundary`` books a
    moving collider's work)."""
    methods = sorted(f"{m['scheme']}-{m['force']}-{m['kernel']}" for m in valid_methods())
    assert len(methods) == 20
    for dim in (2, 3):
        for stage in ("p2g", "g2p", "step", "ledger"):
            variants = {c.variant for c in cases_of(stage, DRAWN_CASES) if c.dim == dim}
            assert set(methods) <= variants, (stage, dim)
            assert {"apic-mls-quadratic-gradient-classic", "apic-classic-quadratic-gradient-mls"} <= variants
        for stage in ("stress", "step", "ledger"):
            types = {m["type"] for c in cases_of(stage) if c.dim == dim for m in c.scene_dict["materials"].values()}
            assert types == set(MATERIAL_TYPES)
        scenes = [c.scene() for c in cases_of("grid_update") if c.dim == dim]
        assert {w.type for s in scenes for w in s.boundary.walls.values()} == set(WALL_TYPES)
        shapes = {type(k.shape).__name__ for s in scenes for k in s.colliders}
        assert len(shapes) == len(COLLIDER_SHAPES) - 1 - (dim == 2)  # disk and sphere are one class
        ledger_shapes = {type(k.shape).__name__ for c in cases_of("ledger") if c.dim == dim
                         for k in c.scene().colliders}
        assert ledger_shapes == shapes
    assert {c.stage for c in ALL_CASES} == set(CONFORMANCE_STAGES)
    # 12 stress + 6 return map + 56 P2G + 46 fused P2G + 14 grid update + 56 G2P + 56 steps + 58 ledgers (the
    # steps' and colliders)
    assert len({c.name for c in DRAWN_CASES}) == len(DRAWN_CASES) == 304
    assert len({c.name for c in ALL_CASES}) == len(ALL_CASES)
    for dim in (2, 3):  # each material alone in the transfers too, so that a one-material code has cases
        for stage in ("p2g", "g2p"):
            alone = [c for c in cases_of(stage) if c.dim == dim and len(c.scene_dict["materials"]) == 1]
            assert {next(iter(c.scene_dict["materials"].values()))["type"] for c in alone} == set(MATERIAL_TYPES)


def test_cases_vary_the_grid_and_the_time_step():
    """What one box and one Δt cannot catch: every case has its own cell counts per axis (not all equal), cell
    size and origin, and the stages that take Δt see many of them, decades apart, all inside the stable range."""
    grids = [c.scene().grid for c in DRAWN_CASES]
    assert all(len(set(g.cells)) > 1 and np.all(g.origin < 0) for g in grids)
    assert max(g.dx for g in grids) / min(g.dx for g in grids) > 50
    for stage in STAGES_WITH_DT:
        scenes = [c.scene() for c in cases_of(stage, DRAWN_CASES)]
        dts = np.array([s.time.dt for s in scenes])
        assert len(set(dts)) == len(dts) >= 5
        cfl = np.array([cfl_number(s) for s in scenes])
        assert cfl.max() <= CFL_RANGE[1] and np.log10(cfl.max() / cfl.min()) > 3
        assert all(float(c.inputs()["dt"]) == s.time.dt for c, s in zip(cases_of(stage, DRAWN_CASES), scenes))
    times = [float(c.inputs()["time"]) for c in cases_of("grid_update", DRAWN_CASES)]
    assert len(set(times)) == len(times) and max(times) / min(times) > 10


def test_states_are_seeded_and_physically_sensible():
    for case in DRAWN_CASES:
        first, again = case.inputs(), case.inputs()
        assert first.keys() == again.keys() and all(np.array_equal(first[k], again[k]) for k in first)
        if "x" not in first:
            assert (first["grid_mass"] == 0).any() and (first["grid_mass"] > 0).any()
            continue
        scene = case.scene()
        grid = scene.grid
        cells = (first["x"] - grid.origin) / grid.dx
        assert cells.min() >= EDGE_CELLS and np.all(cells.max(axis=0) <= np.array(grid.cells) - EDGE_CELLS)
        assert compute_stencil(scene.kernel, first["x"], grid.origin, grid.dx).w.min() >= MIN_WEIGHT
        assert np.all(first["mass"] > 0) and np.all(first["vol0"] > 0)
        if "F" in first:
            assert np.linalg.det(first["F"]).min() > 0.3
        for key in ("J", "Jp"):
            if key in first:
                assert 0.5 < first[key].min() and first[key].max() < 1.5


def test_reference_is_well_conditioned_on_the_cases(rng):
    """A 1e-15 relative change of every input moves every reference output by < 1e-13 of it (the harness's case-wide
    error), the extremes included, and by < 2.5e-13 particle by particle (the per-row error, each on its own scale
    with its floor): a correct backend, rounding differently, can meet rtol = 1e-12 (this failed by 2.5e-7 before
    ``MIN_WEIGHT``, and by 1e-9 at a Neo-Hookean J of 1e-8 before the extremes kept to well-conditioned rungs). The
    change is up to 13 ulps of an entry (three standard deviations of a few hundred); a correct code's own rounding is
    one or two, and a quarter of the tolerance leaves that four times over particle by particle."""
    for case in ALL_CASES:
        inputs = case.inputs()
        nudged = nudged_inputs(case, inputs, rng)
        reference, moved = case.reference(inputs), case.reference(nudged)
        errors, _ = compare_outputs(moved, reference, natural=case_natural_scales(case.scene(), inputs, reference))
        assert max(e.case_wide for e in errors.values()) < 1e-13, (case.name, errors)
        assert max(errors.values()) < 2.5e-13, (case.name, errors)


def nudged_inputs(case, inputs, rng):
    """``inputs`` with every floating entry changed by 1e-15 relative (Gaussian), but the positions of a case whose
    positions are exact by design (a particle on a node line or at the domain's edge of an exact grid, which every
    code sees exactly there: :func:`mpmref.conformance.cases.exact_grid`), and a particle that would leave the
    positions its kernel allows."""
    nudged = {k: a * (1.0 + 1e-15 * rng.standard_normal(a.shape)) if a.ndim and a.dtype.kind == "f" else a
              for k, a in inputs.items()}
    if "x" in inputs and case.extreme is not None and case.extreme.exact_grid:
        nudged["x"] = inputs["x"]
    if "x" in inputs:
        scene = case.scene()
        xi = (nudged["x"] - scene.grid.origin) / scene.grid.dx
        legal = (xi >= scene.kernel.low_margin) & (xi < np.array(scene.grid.cells) - scene.kernel.high_margin)
        nudged["x"] = np.where(legal, nudged["x"], inputs["x"])
    return nudged


def test_float32_reference_is_within_a_tenth_of_its_tolerance_of_float64():
    """The float32 threshold leaves ten times the float32 reference's own error for the candidate (by the harness's
    error rule). Every output is float32 but the ledger's, which books in float64 whatever the run's dtype, and the
    return map's wave speeds, float64 as the level rule takes them (the wave_speeds stage's too)."""
    for case in make_cases(dtype="float32"):
        wide = ConformanceCase(case.stage, case.dim, case.variant, {**case.scene_dict, "dtype": "float64"},
                               extreme=case.extreme, seed_label=case.seed_label)
        inputs = case.inputs()
        exact = wide.reference({k: a.astype(np.float64) if a.dtype == np.float32 else a for k, a in inputs.items()})
        narrow = case.reference(inputs)
        assert all(value.dtype == (np.float64 if case.stage == "ledger" or name == "wave_speed" else np.float32)
                   for name, value in narrow.items())
        errors, _ = compare_outputs(narrow, exact, natural=case_natural_scales(case.scene(), inputs, exact))
        assert max(errors.values()) < DEFAULT_RTOL["float32"] / 10, (case.name, errors)


def test_relative_error_definition():
    ref = np.array([[1.0, -4.0], [2.0, 0.0]])
    assert relative_error(ref + np.array([[0.0, 0.0], [0.0, 2e-3]]), ref) == pytest.approx(5e-4)
    assert relative_error(np.array([0.0, 3e-7]), np.zeros(2)) == pytest.approx(3e-7)  # all-zero reference: absolute
    assert relative_error(ref[:1], ref) == math.inf
    assert relative_error(np.where(ref == 0.0, np.nan, ref), ref) == math.inf
    assert relative_error(ref.astype(np.float32), ref) == 0.0


# ---------------------------------------------------------------------------------------- the candidates
def covering(cases):
    """The cases that each bring a value not met before on an axis a compiled backend specialises its kernels on
    (scheme, force, velocity gradient, kernel, the set of materials), in the catalogue's order: every value of every
    axis, at about half the kernels to compile (14 of the 28 2D cases of a transfer stage)."""
    seen, kept = set(), []
    for case in cases:
        method = case.scene().method
        values = {("scheme", method.scheme), ("force", method.force), ("gradient", method.velocity_gradient),
                  ("kernel", method.kernel), ("materials", tuple(sorted(case.materials)))}
        if values - seen:
            kept.append(case)
            seen |= values
    return kept


def conformance_runs():
    """Every backend on the 2D and on the 3D cases, one test per stage (so that a parallel test run can share the
    compile-heavy stages out), the stages of asynchronous stepping included; the ``slow`` set (``pytest -m slow``, run
    by CI) has the rest of a compiled backend's cases. On a fresh Numba cache each configuration compiles its kernels
    (about 3 s of one core), so the default run checks a compiled backend on every value of every axis in 2D
    (:func:`covering`) and leaves to the slow set the other 2D combinations, the 3D half (17 more configurations) and
    the stages of asynchronous stepping (their kick gathers compile per transfer: about 50 s of one core in 2D)."""
    def part(backend, dim, stage, which):
        slow = backend != "numpy" and (dim == 3 or stage in ASYNC_CONFORMANCE_STAGES or which == "rest")
        suffix = "" if which in ("all", "covering") else f"-{which}"
        return pytest.param(backend, dim, stage, which, marks=[pytest.mark.slow] if slow else [],
                            id=f"{backend}-{dim}d-{stage}{suffix}")

    return [part(backend, dim, stage, which) for backend in BACKENDS for dim in (2, 3)
            for stage in CONFORMANCE_STAGES + ASYNC_CONFORMANCE_STAGES
            for which in (("all",) if backend == "numpy" or dim == 3 else ("covering", "extremes", "rest"))
            if conformance_cases(backend, dim, stage, which)]


def conformance_cases(backend, dim, stage, which):
    """The cases of one run of :func:`conformance_runs`: all of them, the drawn ones that cover every axis, the
    extremes (which compile nothing more: their methods and materials are among the covering ones'), or the rest."""
    cases = [c for c in ALL_CASES + ASYNC_CASES if c.dim == dim and c.stage == stage]
    if which in ("all", "extremes"):
        return cases if which == "all" else [c for c in cases if c.extreme is not None]
    drawn = [c for c in cases if c.extreme is None]
    kept = covering(drawn)
    return kept if which == "covering" else [c for c in drawn if c not in kept]


@pytest.mark.parametrize("backend, dim, stage, which", conformance_runs())
def test_every_backend_conforms_at_1e_12(backend, dim, stage, which):
    """Adding a name to mpmref.backends.BACKENDS is all it takes to check a backend here; the reference
    itself reproduces its outputs exactly."""
    cases = conformance_cases(backend, dim, stage, which)
    report = check(backend, cases, rtol=1e-12)
    assert report.passed, report.table()
    assert not report.skipped and len(report.results) == len(cases) > 0
    if backend == "numpy":  # the reference reproduces itself exactly; its fused P2G its unfused one plus dt f
        assert report.worst().error <= (2e-15 if stage == "p2g_fused" else 0.0)


class PerturbedStress(NumpyBackend):
    """The reference with every Kirchhoff stress 1e-9 too large (P2G and step use it too)."""

    def stress(self, particles):
        return super().stress(particles) * (1.0 + 1e-9)


class AffineFreeP2G(NumpyBackend):
    """The reference whose P2Gs, plain and fused, drop APIC's affine momentum C_p (x_i - x_p) (step uses them too)."""

    @staticmethod
    def affine_free(particles):
        return particles if particles.C is None else particles.with_(C=np.zeros_like(particles.C))

    def p2g(self, particles, prepared=None):
        return super().p2g(self.affine_free(particles), prepared)

    def p2g_fused(self, particles, dt, prepared=None):
        return super().p2g_fused(self.affine_free(particles), dt, prepared)


def perturbed_stress_error(case, factor):
    r"""The judged error of a stress ``factor`` too large, from the rule's definition (docs/conformance.md, "The
    error"): each particle's :math:`|\tau_p|` scaled by ``factor`` over the larger of :math:`|\tau_p|` and
    :math:`\phi \max(S, n_p)`, and case-wide :math:`S` over :math:`\max(S, \phi \max_p n_p)`; :math:`S` the largest
    entry, :math:`n_p` the particle's natural scale, :math:`\phi` the float64 floor."""
    inputs = case.inputs()
    tau = np.abs(case.reference(inputs)["tau"]).reshape(len(inputs["x"]), -1).max(axis=1)
    natural = case_natural_scales(case.scene(), inputs, {"tau": tau})["tau"]
    largest, floor = tau.max(), ROW_FLOOR["float64"]
    row = np.max(factor * tau / np.maximum(tau, floor * np.maximum(largest, natural)))
    return max(row, factor * largest / max(largest, floor * natural.max()))


def test_perturbed_stress_fails_exactly_the_stages_that_use_the_stress():
    """Every stress and P2G case fails, a stress case by the error the rule predicts (:func:`perturbed_stress_error`:
    1e-9 where the stress is of its stiffness, less where it is a small strain's). A fused P2G moves by the 1e-9 of
    its force impulse, 1e-9 max|Δt f| / max|mv + Δt f| (or over the floor of the impulse's natural scale, where that
    is larger), which is below 1e-12 where Δt f is small beside the momentum: those cases pass, the others fail,
    as predicted case by case. A step fails unless its Δt is so short that the change stays below 1e-12 of the
    state (CFL numbers below 1e-2: the harness draws some). The ledger sees the stress through the force's work only:
    P2G's kinetic energy (mass and momentum) is exactly the reference's, and a ledger case fails where the work
    Δt Σ f·v is large enough for 1e-9 of it to pass 1e-12 of the energy scale. (The drawn cases: the extremes are
    tests/test_extremes.py's.)"""
    report = check(PerturbedStress, PLANE_CASES)
    assert report.failed_stages() == {"stress", "p2g", "p2g_fused", "step", "ledger"}
    ledgers = [r for r in report.results if r.case.stage == "ledger"]
    assert all(r.errors["ledger_p2g_transfer"] == 0.0 for r in ledgers)
    assert {r.worst_output for r in ledgers if not r.passed} <= {"ledger_internal_work", "ledger_energy_change",
                                                                  "ledger_integration"}
    failed = [r.case for r in report.failures()]
    assert len([c for c in failed if c.stage in ("stress", "p2g")]) == len(cases_of("stress", PLANE_CASES)
                                                                          + cases_of("p2g", PLANE_CASES))
    for result in (r for r in report.results if r.case.stage == "stress"):
        assert result.error == pytest.approx(perturbed_stress_error(result.case, 1e-9), rel=1e-3), result.case.name
    for result in (r for r in report.results if r.case.stage == "p2g_fused"):
        inputs, scene = result.case.inputs(), result.case.scene()
        gs = NumpyBackend(scene).p2g(particles_from(inputs))
        impulse = scene.time.dt * gs.force
        natural = case_natural_scales(scene, inputs, {"grid_momentum_after_force": impulse})
        scale = max(np.abs(gs.momentum + impulse).max(),
                    ROW_FLOOR["float64"] * natural.get("grid_momentum_after_force", 0.0))
        predicted = 1e-9 * np.abs(impulse).max() / scale
        case_wide = result.errors["grid_momentum_after_force"].case_wide
        assert case_wide == pytest.approx(predicted, rel=0.05, abs=2e-15), result.case.name
        assert result.error >= case_wide  # per node, each on its own momentum, it is no smaller
    passing_steps = [r.case for r in report.results if r.case.stage == "step" and r.passed]
    assert passing_steps and all(cfl_number(c.scene()) < 1e-2 for c in passing_steps)
    assert "FAILED" in report.table()


def test_dropping_the_affine_p2g_term_fails_only_affine_p2g_steps_and_ledgers():
    """The affine schemes' P2G cases fail, and their ledgers: the grid's kinetic energy after P2G changes, so
    ``ledger_p2g_transfer`` moves (by percents of the energy scale on these random states)."""
    report = check(AffineFreeP2G, PLANE_CASES)
    assert report.failed_stages() == {"p2g", "p2g_fused", "step", "ledger"}
    for stage in ("p2g", "p2g_fused", "ledger"):
        failed = {r.case.name for r in report.failures() if r.case.stage == stage}
        assert failed == {c.name for c in cases_of(stage, PLANE_CASES) if c.scene().transfer.affine}
    assert all(r.errors["ledger_p2g_transfer"] > 1e-6 for r in report.failures() if r.case.stage == "ledger")
    assert report.worst().worst_output in ("grid_momentum", "grid_momentum_after_force", "x", "v", "C", "F", "J",
                                           "modes")


def test_mapping_candidate_skips_missing_stages_and_reports_exceptions():
    def broken_p2g(scene, particles):
        raise RuntimeError("not implemented for this scene")

    candidate = {"stress": lambda scene, particles: NumpyBackend(scene).stress(particles), "p2g": broken_p2g}
    report = check(candidate, ALL_CASES)
    assert {c.stage for c in report.skipped} == set(CONFORMANCE_STAGES) - {"stress", "p2g"}
    assert all(r.passed for r in report.results if r.case.stage == "stress")
    assert report.failed_stages() == {"p2g"}
    assert all("RuntimeError: not implemented" in r.note for r in report.failures())
    table = report.table()
    assert not report.passed and "does not provide the stage grid_update" in table and "not applicable" in table


def test_factory_returning_a_mapping_and_missing_outputs():
    """A factory may return a dict of stage callables; a G2P that forgets C fails with a note naming it."""
    def factory(scene):
        backend = NumpyBackend(scene)
        return {"g2p": lambda *args: backend.g2p(*args).with_(C=None)}

    report = check(factory, cases_of("g2p"))
    affine = {c.name for c in cases_of("g2p") if c.scene().transfer.affine}
    assert {r.case.name for r in report.failures()} == affine
    assert all("no output C" in r.note for r in report.failures())


def test_invalid_candidates_and_names_are_refused():
    with pytest.raises(TypeError, match="factory"):
        check(42, cases_of("stress")[:1])
    with pytest.raises(TypeError, match="P2G"):
        check({"P2G": print}, cases_of("stress")[:1])
    with pytest.raises(ValueError, match="p2q"):
        make_cases(stages=("p2q",))


# ------------------------------------------------------------------------------------------- the export
@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("vectors")
    export(folder, ALL_CASES)
    return folder


def test_export_writes_the_inputs_and_a_complete_manifest(exported):
    """The files hold each case's inputs and describe themselves; that their outputs are the reference's is
    shown by the replay candidate below, which passes at zero error."""
    manifest = json.loads((exported / "manifest.json").read_text())
    assert manifest["format"] == "mpmref-conformance" and manifest["version"] == 5
    assert {"nodes", "particles", "material", "modes", "error"} <= set(manifest["conventions"])
    entries = {e["name"]: e for e in manifest["cases"]}
    files = [e["file"] for e in entries.values()] + ["manifest.json"]
    assert sorted(p.name for p in exported.iterdir()) == sorted(files)  # no temporary files left
    for case in ALL_CASES:
        entry = entries[case.name]
        inputs, outputs = load_vectors(exported / entry["file"])
        expected = case.inputs()
        assert inputs.keys() == expected.keys() and all(np.array_equal(inputs[k], expected[k]) for k in inputs)
        assert all(inputs[k].dtype == expected[k].dtype for k in inputs)
        shapes = {**{f"in_{k}": a.shape for k, a in inputs.items()},
                  **{f"out_{k}": a.shape for k, a in outputs.items()}}
        assert {k: tuple(v["shape"]) for k, v in entry["arrays"].items()} == shapes
        assert entry["stage"] == case.stage and entry["rtol"] == 1e-12
        assert Scene.from_dict(entry["scene"]).dim == case.dim
        n_nodes = entry["resolved"]["grid"]["n_nodes"]
        assert n_nodes == np.prod(np.array(case.scene().grid.cells) + 1)
        for name, array in {**inputs, **outputs}.items():
            if name.startswith("grid_"):
                assert array.shape[0] == n_nodes
        if "modes" in inputs:
            assert len(entry["resolved"]["polypic_modes"]) == inputs["modes"].shape[1]
        if case.variant == "colliders":
            shapes = {c["shape"] for c in entry["resolved"]["colliders"]}
            assert shapes == {"plane", "ball", "box"} | ({"cylinder"} if case.dim == 3 else set())


def replay_candidate(folder):
    """A candidate that knows nothing but the exported files: each stage finds the case whose inputs are
    its arguments (by stage and the bytes of the positions, or of the grid masses) and returns the stored
    outputs."""
    stored = {}
    for entry in json.loads((folder / "manifest.json").read_text())["cases"]:
        inputs, outputs = load_vectors(folder / entry["file"])
        key = inputs["grid_mass"] if entry["stage"] == "grid_update" else inputs["x"]
        stored[entry["stage"], key.tobytes()] = outputs

    def out(stage, key):
        return stored[stage, key.tobytes()]

    def evolved(stage, particles):
        return particles.with_(**{k: v for k, v in out(stage, particles.x).items() if k != "wave_speed"})

    def return_map(scene, particles, wave_speed=None):
        if wave_speed is not None:  # the stage's optional second output, stored with the particles'
            wave_speed[:] = out("return_map", particles.x)["wave_speed"]
        return evolved("return_map", particles)

    return {
        "stress": lambda scene, p: out("stress", p.x)["tau"],
        "return_map": return_map,
        "p2g": lambda scene, p: GridState(**{k[5:]: v for k, v in out("p2g", p.x).items()}),
        "p2g_fused": lambda scene, p, dt: GridState(mass=out("p2g_fused", p.x)["grid_mass"],
                                                    momentum=out("p2g_fused", p.x)["grid_momentum_after_force"]),
        "grid_update": lambda scene, gs, dt, time: (out("grid_update", gs.mass)["grid_v"],
                                                    out("grid_update", gs.mass)["grid_v_tilde"]),
        "g2p": lambda scene, p, v, v_tilde, dt: evolved("g2p", p),
        "step": lambda scene, p, dt, time: evolved("step", p),
        "ledger": lambda scene, p, dt, time: out("ledger", p.x),
    }


def test_a_candidate_built_from_the_exported_vectors_alone_passes(exported):
    """Zero error on every case: the stored outputs are bit for bit the reference's on the same inputs. (But the
    multi-step cases, whose step the harness calls ``in_steps`` times: stored outputs answer the first call only.)"""
    cases = [c for c in ALL_CASES if c.steps == 1]
    report = check(replay_candidate(exported), cases)
    assert report.passed and not report.skipped and len(report.results) == len(cases)
    assert report.worst().error == 0.0


# ----------------------------------------------------------------------------------------------- the CLI
def cli(argv):
    parser = argparse.ArgumentParser(prog="mpmref")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_cli_check_prints_the_table_and_exits_0_or_1(capsys, monkeypatch):
    assert cli(["conformance", "check", "--backend", "numpy", "--dim", "2", "--stage", "stress"]) == 0
    out = capsys.readouterr().out
    assert "PASSED: 21 of 21" in out and "stress-2d" in out  # 6 drawn, 15 at the extremes
    monkeypatch.setattr("mpmref.conformance.report.resolve", lambda reference: PerturbedStress)
    assert cli(["conformance", "check", "--backend", "numpy", "--dim", "3", "--stage", "stress", "grid_update"]) == 1
    out = capsys.readouterr().out
    assert "FAILED: 8 of 29" in out and "stress-3d-snow" in out  # 21 stress cases fail, 8 grid updates pass


def test_cli_check_shows_progress_on_stderr_unless_told_not_to(capsys):
    """The bar names each case on standard error; standard output keeps only the table."""
    argv = ["conformance", "check", "--backend", "numpy", "--dim", "2", "--stage", "stress"]
    assert cli(argv) == 0
    out, err = capsys.readouterr()
    assert "conformance: 100%" in err and "21/21" in err and "stress-2d" in err
    assert "conformance:" not in out and out.splitlines()[0].startswith("stage")
    assert cli(argv + ["--no-progress"]) == 0
    quiet_out, quiet_err = capsys.readouterr()
    assert quiet_err == "" and quiet_out == out


def test_cli_export_selects_dimension_stage_and_dtype(tmp_path, capsys):
    assert cli(["conformance", "export", str(tmp_path / "v"), "--dim", "3", "--stage", "grid_update",
                "--dtype", "float32"]) == 0
    assert "wrote 8 cases" in capsys.readouterr().out  # 7 drawn and the nodes without mass beside full ones
    entries = json.loads((tmp_path / "v" / "manifest.json").read_text())["cases"]
    assert len(entries) == 8
    assert all(e["dim"] == 3 and e["stage"] == "grid_update" and e["name"].endswith("-f32") for e in entries)
    assert all(e["rtol"] == DEFAULT_RTOL["float32"] for e in entries)
    inputs, outputs = load_vectors(tmp_path / "v" / entries[0]["file"])
    assert inputs["grid_mass"].dtype == np.float32 and outputs["grid_v"].dtype == np.float32
