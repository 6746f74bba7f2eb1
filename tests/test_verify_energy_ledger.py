"""The energy-ledger case (verification/energy_ledger): its quick preset holds, each of its checks fails on the bug
it is there to catch, and its report carries the split, the stacked areas, the per-particle terms and the tables."""

import argparse
import json
from dataclasses import replace

import meshio
import numpy as np
import PIL.Image
import pytest
from helpers import assert_every_figure_has_a_caption

from mpmref.backends.numpy import backend as numpy_backend
from mpmref.backends.numpy.transfers import wall_bands
from mpmref.observe.ledger import ASYNC_COLUMNS, ASYNC_TERMS
from verification import energy_ledger as case
from verification.energy_ledger import reporting, runs
from verification.framework.cli import add_parser
from verification.framework.common import failed


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


def checks_named(result, text):
    return [c for c in case.checks(result) if text in c.name]


def test_every_check_of_the_quick_preset_holds(result):
    failing = [c.line() for c in failed(case.checks(result))]
    assert not failing, "\n".join(failing)


def test_the_checks_cover_the_signs_theory_fixes_on_every_run_it_fixes_them(result):
    """Transfers for PIC, APIC, MLS-MPM and PolyPIC (not FLIP, not CPIC); PolyPIC's G2P both ways; static walls
    wherever walls act (not the disks' open domain); plasticity for snow and sand; the candidate on each compared
    run; the friction block and the integration order once."""
    names = [c.name for c in case.checks(result)]
    projection = ["jelly-pic", "jelly-apic_classic", "jelly-mls", "jelly-polypic", "snow88", "sand", "colliding_disks",
                  "stork2d"]
    assert sorted(n.split(":")[0] for n in names if "p2g_transfer in one step" in n) == sorted(projection)
    assert [n.split(":")[0] for n in names if "|g2p_transfer|" in n] == ["jelly-polypic"]
    assert sorted(n.split(":")[0] for n in names if "plastic in one step" in n) == ["sand", "snow88"]
    walls = {n.split(":")[0] for n in names if "boundary in one step" in n}
    assert walls == set(result["params"].runs) - {"colliding_disks"}
    assert sorted(n.split(":")[0] for n in names if "numba ledger" in n) == sorted(case.Params.quick().compared)
    assert sum("sum of the terms" in n for n in names) == len(result["params"].runs)


def test_each_run_books_the_stages_it_exercises(result):
    """The checks are not vacuous: the walls take energy where the bodies land, the return maps dissipate in snow88
    and sand, PolyPIC's modes change as the particles move, and the candidate books the same steps."""
    by = {r["key"]: r for r in result["runs"]}
    last = {key: dict(zip(ASYNC_COLUMNS, r["ledger"][-1])) for key, r in by.items()}
    for key in ("jelly-mls", "snow88", "sand"):
        assert last[key]["boundary"] < -1e-4 * runs.run_scale(by[key])
    for key in ("snow88", "sand"):
        assert last[key]["plastic"] < -1e-2 * runs.run_scale(by[key])
    assert abs(last["jelly-polypic"]["advection"]) > 1e-4 * runs.run_scale(by["jelly-polypic"])
    # the asynchronous stork: its level interfaces exchange energy, which only its ledger has a term for
    assert abs(last["stork2d"]["interface"]) > 1e-8 * runs.run_scale(by["stork2d"])
    assert all(last[key]["interface"] == 0.0 for key in by if key != "stork2d")
    assert all(len(books) == 2 for books in result["compared"].values())


def test_the_stacked_terms_are_the_measured_change(result):
    """At every sampled step the cumulative terms add up to the diagnostics' change of total energy (the figure's
    black line and dots)."""
    for r in result["runs"]:
        terms = sum(v[r["sampled_steps"]] for v in runs.terms_of(r).values())
        energy = runs.total_energy(r)
        assert terms == pytest.approx(energy - energy[0], abs=1e-12 * runs.run_scale(r))


# ------------------------------------------------------------------------------------- checks that can fail
def small(**changes):
    return replace(case.Params.quick(), **changes)


def floor_that_pushes(grid_update):
    """A floor that sends its band's nodes up 1 cm/s faster than the walls leave them: at a node resting on it the
    'impulse' m (v - v*) does positive work. (A restitution wall would not do: with a coefficient e <= 1 it adds no
    energy, B_i ~ m |v*_n|^2 (1 + e)(e - 1) / 2 when the forces change the velocity little in a step.)"""
    def pushing(self, grid_state, dt, time=0.0):
        v, v_tilde = grid_update(self, grid_state, dt, time)
        floor = next(band for name, band, _ in wall_bands(self.scene.grid, self.scene.boundary.width)
                     if name == "y_min")
        v = v.copy()
        v[floor & (grid_state.mass > 0), 1] += 0.01
        return v, v_tilde

    return pushing


def g2p_that_injects(g2p):
    """Every G2P velocity 1 % too large: G2P adds kinetic energy, which no projection can."""
    def injecting(self, *args, **kwargs):
        new = g2p(self, *args, **kwargs)
        return new.with_(v=1.01 * new.v)

    return injecting


def return_map_that_stretches(return_map):
    """The return map followed by a 0.1 % stretch of F: the stored energy rises in the return map."""
    def stretching(self, particles):
        new = return_map(self, particles)
        return new.with_(F=1.001 * new.F)

    return stretching


#: per checked term, the planted bug (the stage it replaces and how) and the run that shows it
PLANTED = {"boundary": ("grid_update", floor_that_pushes, "sand"),
           "g2p_transfer": ("g2p", g2p_that_injects, "jelly-pic"),
           "plastic": ("return_map", return_map_that_stretches, "sand")}


@pytest.mark.parametrize("term", PLANTED)
def test_a_stage_that_makes_energy_fails_the_check_of_its_term(term, monkeypatch):
    """Each planted bug makes energy in one stage: the check of that stage's term fails, by orders of magnitude."""
    stage, plant, key = PLANTED[term]
    monkeypatch.setattr(numpy_backend.NumpyBackend, stage, plant(getattr(numpy_backend.NumpyBackend, stage)))
    r = runs.run_example(small(runs=(key,), compared=()), key, "numpy")
    (check,) = [c for c in case.reporting.run_checks(r) if f"{term} in one step" in c.name]
    assert not check.passed and check.value > 1e3 * check.bound


def test_a_candidate_with_a_wrong_force_fails_the_candidate_check():
    """The MLS force with the cubic kernel's D_p (3/4 of every force; tests/planted_backends.py) as the candidate:
    its ledger's internal work differs from the reference's by far more than round-off."""
    params = small(runs=("jelly-mls",), compared=("jelly-mls",), candidate="planted_backends:WrongMlsInertia")
    r = runs.run_example(params, "jelly-mls", "numpy")
    worst = max(r["compared"], key=lambda b: b["error"])
    assert worst["error"] > 1e-6 and worst["worst"] in ("ledger_internal_work", "ledger_integration",
                                                         "ledger_energy_change", "ledger_g2p_transfer")


def test_friction_and_integration_figures_are_the_physics():
    """The friction block's boundary term is mu m g d within 5 %; the integration error's slope is 1 within 0.2
    (the energy case's oscillating jelly): measured here as the case measures them."""
    params = case.Params.quick()
    f = runs.run_friction(params, "numpy")
    assert 0.04 < f["distance"][-1] < 0.07  # it slides, and has not stopped (1 m/s at mu g = 3 m/s^2 for 0.06 s)
    assert case.reporting.friction_ratio(f) == pytest.approx(1.0, abs=0.05)
    i = runs.run_integration(replace(params, integration_t_end=0.005), "numpy")
    assert case.reporting.integration_slope(i) == pytest.approx(1.0, abs=0.2)


# ---------------------------------------------------------------------------------------------- the scenes
def test_skipping_free_flight_is_the_free_fall_of_each_body():
    """free_flight moves each body along v t + g t^2 / 2 and gives it v + g t (the examples' bodies start at rest)."""
    data = {"dim": 2, "gravity": [0.0, -10.0], "bodies": [{"lower": [0.1, 0.5], "upper": [0.2, 0.6]},
                                                          {"center": [0.5, 0.5], "velocity": [1.0, 0.0]}]}
    out = runs.free_flight(data, 0.1)
    assert out["bodies"][0]["lower"] == pytest.approx([0.1, 0.45]) and out["bodies"][0]["velocity"] == [0.0, -1.0]
    assert out["bodies"][1]["center"] == pytest.approx([0.6, 0.45]) and out["bodies"][1]["velocity"] == [1.0, -1.0]


def test_coarsening_keeps_the_mass_of_a_body_sampled_by_count():
    full = runs.example_scene(runs.RUN["snow88"], case.Params())
    coarse = runs.example_scene(runs.RUN["snow88"], case.Params.quick())
    assert coarse.grid.cells == (32, 32) and full.grid.cells == (64, 64)
    from mpmref.scene.sampling import sample_particles

    assert sample_particles(coarse).mass.sum() == pytest.approx(sample_particles(full).mass.sum(), rel=1e-12)


# ---------------------------------------------------------------------------------------------- the report
def last_frame(folder):
    return sorted(folder.glob("particles_*.vtu"))[-1]


def test_report_writes_the_split_the_figures_and_the_per_particle_terms(result, tmp_path):
    paths = case.report(result, tmp_path)
    assert all(p.exists() for p in paths)
    assert_every_figure_has_a_caption(tmp_path)
    for png in tmp_path.glob("*.png"):            # each readable where a report shows it, about 600 pixels wide
        assert PIL.Image.open(png).width <= 1.15 * reporting.WIDTH * 110, png.name
    text = (tmp_path / "energy_ledger.md").read_text()
    assert all(f"| {r['key']} |" in text for r in result["runs"]) and "FAIL" not in text
    sand = meshio.read(last_frame(tmp_path / "vtk" / "sand"))
    plastic = sand.point_data["ledger_plastic"]
    last = dict(zip(ASYNC_COLUMNS, next(r for r in result["runs"] if r["key"] == "sand")["ledger"][-1]))
    assert plastic.sum() == pytest.approx(last["plastic"], rel=1e-9) and plastic.min() < 0.0
    poly = meshio.read(last_frame(tmp_path / "vtk" / "jelly-polypic"))
    assert "ledger_advection" in poly.point_data and "ledger_plastic" not in poly.point_data


def test_tables_carry_each_runs_split(result):
    tables = case.tables(result)
    rows = {row["run"]: row for row in tables["split"]}
    assert set(rows) == set(result["params"].runs)
    for row in rows.values():
        assert sum(row[t] for t in ASYNC_TERMS) == pytest.approx(row["energy_change"],
                                                                 abs=1e-12 * abs(row["E0"]) + 1e-15)
    json.dumps(tables, allow_nan=False)
    assert len(tables["candidate"]) == 2 * len(result["compared"])


def test_verify_writes_the_tables_into_results_json(monkeypatch, tmp_path):
    """``mpmref verify energy_ledger``: the case's tables travel into ``results.json`` (a smaller quick preset)."""
    smaller = small(runs=("jelly-mls", "sand"), compared=("sand",))
    monkeypatch.setattr(case.Params, "quick", classmethod(lambda cls: smaller))
    parser = argparse.ArgumentParser(prog="mpmref")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["verify", "energy_ledger", "--quick", "--workers", "1", "--out", str(tmp_path),
                              "--no-progress"])
    assert args.func(args) == 0
    data = json.loads((tmp_path / "results.json").read_text())
    (entry,) = data["cases"]
    assert entry["backends"] == ["numpy", "numba"]
    assert [row["run"] for row in entry["tables"]["split"]] == ["jelly-mls", "sand"]
    assert set(entry["tables"]["split"][0]) >= {"E0", "measured_change", *ASYNC_COLUMNS}
    assert np.isfinite(entry["tables"]["candidate"][0]["error"])
