"""``mpmref bench``: its scenes, its JSON document and tables, and the Taichi peer's agreement with mpmref.

No test here looks at a timing (timings live in the benchmark, never in tests): they check what is
measured, the shape of what is reported, and that the peer computes the same physics.
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pytest

import mpmref.peers
from mpmref import MpmrefError, Scene, SceneBuilder
from mpmref.backends import make_backend
from mpmref.bench import SCHEMA, SECTIONS, BenchOptions, add_parser, options_from_args, run_bench
from mpmref.bench.opcount import predicted_ratio
from mpmref.bench.peer import clear_of_walls, frobenius_max, mean_position_bound, run_peer
from mpmref.bench.report import render_peer
from mpmref.bench.scenes import (
    ThroughputCase,
    mpm88_scene,
    table2_cells,
    table2_particles,
    table2_scene,
    throughput_cases,
)
from mpmref.bench.table2 import table2_ratios
from mpmref.conformance import relative_error
from mpmref.errors import BackendError
from mpmref.scene.sampling import sample_particles
from mpmref.steppers import substep

ROOT = Path(__file__).resolve().parent.parent
TIMING_KEYS = {"first_call_s", "times_s", "median_s"}


def parse(argv):
    parser = argparse.ArgumentParser(prog="mpmref")
    add_parser(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["bench", *argv])


# ------------------------------------------------------------------------------------------- scenes
@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("dim", [2, 3])
def test_table2_block_has_2_to_the_d_particles_per_cell_at_quarter_cell_offsets(dtype, dim):
    """8 per cell in 3D (the talk's set-up), 4 in its 2D counterpart: the cell's corners at +-dx/4."""
    cells = 3
    scene = table2_scene(cells, "mls", dtype, dim)
    x = table2_particles(scene).x.astype(np.float64)
    xi = (x - scene.grid.origin) / scene.grid.dx
    cell = np.floor(xi).astype(int)
    offset = xi - cell - 0.5  # from the cell centre, in cells
    occupied, counts = np.unique(cell, axis=0, return_counts=True)
    assert len(occupied) == cells**dim and np.all(counts == 2**dim)
    assert occupied.min() == 2 and occupied.max() == 2 + cells - 1  # the block sits inside the padding
    np.testing.assert_allclose(np.abs(offset), 0.25, atol=8 * np.finfo(dtype).eps * xi.max())
    corners = {(tuple(c), tuple(np.sign(o).astype(int))) for c, o in zip(cell, offset)}
    assert len(corners) == len(x)  # the 8 particles of a cell are its 8 points centre +- dx/4


def test_table2_methods_are_classic_mpm_and_mls_mpm():
    mpm, mls = table2_scene(2, "mpm").method, table2_scene(2, "mls").method
    assert (mpm.scheme, mpm.force, mpm.kernel) == ("apic", "classic", "quadratic")
    assert (mls.scheme, mls.force, mls.kernel) == ("mls", "mls", "quadratic")
    assert table2_cells(1_000_000) == 50 and table2_cells(8_000_000) == 100
    assert table2_cells(262_144, dim=2) == 256 and table2_cells(1_000_000, dim=2) == 500


def test_throughput_cases_have_the_issue_sizes():
    scenes = {c.name: c.scene("float32") for c in throughput_cases()}
    sizes = {name: (sample_particles(scene).n, scene.grid.cells) for name, scene in scenes.items()}
    assert sizes == {"mpm88": (32768, (128, 128)), "fluid3d": (65536, (64, 64, 64)), "large2d": (262144, (512, 512))}


def test_mpm88_scene_is_the_example_with_another_particle_count():
    example = Scene.from_toml(ROOT / "examples" / "mpm88.toml")
    ours = mpm88_scene(count=8192)
    for attribute in ("dim", "method", "materials", "boundary"):
        assert getattr(ours, attribute) == getattr(example, attribute), attribute
    assert ours.grid.cells == example.grid.cells and ours.time.dt == example.time.dt
    np.testing.assert_array_equal(ours.gravity, example.gravity)
    a, b = ours.bodies[0].params, example.bodies[0].params
    for key in ("lower", "upper", "velocity", "sampling", "seed", "count"):
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


# --------------------------------------------------------------------------------- JSON and tables
def test_bench_no_progress_leaves_standard_error_empty(capsys):
    args = parse(["--quick", "--size", "64", "--backends", "numpy", "--dtype", "f64", "--threads", "1",
                  "--repeats", "1", "--steps", "1", "--only", "table2", "--no-memory", "--no-progress"])
    assert args.func(args) == 0
    out, err = capsys.readouterr()
    assert err == "" and "Table 2" in out



def test_bench_writes_the_json_schema_and_prints_the_tables(tmp_path, capsys):
    from mpmref.bench.goals import goals

    path = tmp_path / "bench.json"
    args = parse(["--quick", "--size", "64", "--backends", "numpy", "--dtype", "f64", "--threads", "1",
                  "--repeats", "2", "--steps", "1", "--json", str(path)])
    assert args.func(args) == 0
    out, err = capsys.readouterr()
    sections = ("table2", "table2_2d", "throughput", "stages", "scaling", "domain", "cpic", "busy", "ledger")
    for i, section in enumerate(sections, 1):
        assert f"[{i}/9] {section}: started" in err and f"[{i}/9] {section}: finished in " in err
    assert "started" not in out
    results = json.loads(path.read_text())
    assert results["schema"] == SCHEMA and results["peer"] is None
    assert set(results) >= {"created_utc", "environment", "options", *SECTIONS}

    table2 = results["table2"]
    assert table2["setup"]["particles"] == 64 and table2["setup"]["cells_per_side"] == 2
    stages = {(t["method"], t["stage"]) for t in table2["timings"]}
    assert stages == {(m, s) for m in ("mpm", "mls") for s in ("prepare", "stress", "p2g", "g2p")}
    for t in table2["timings"]:
        assert TIMING_KEYS <= set(t) and len(t["times_s"]) == 2 and t["median_s"] > 0
    ratio = table2["ratios"][0]
    median = {(t["method"], t["stage"]): t["median_s"] for t in table2["timings"]}
    assert ratio["p2g"] == pytest.approx(median[("mpm", "p2g")] / median[("mls", "p2g")])
    assert ratio["g2p"] == pytest.approx(median[("mpm", "g2p")] / median[("mls", "g2p")])
    transfer = {m: median[(m, "p2g")] - median[(m, "stress")] for m in ("mpm", "mls")}
    if min(transfer.values()) > 0:
        assert ratio["p2g_minus_stress"] == pytest.approx(transfer["mpm"] / transfer["mls"])
    else:  # timing noise at this tiny size: no ratio rather than a meaningless one
        assert ratio["p2g_minus_stress"] is None
    memory = table2["memory"][0]
    assert memory["particle_bytes"] == 64 * (3 + 3 + 9 + 9 + 1 + 1) * 8 + 64 * 4 + 64 * 8  # ... + material + id
    assert memory["grid_bytes"] == 7**3 * 7 * 8 and memory["step_peak_growth_bytes"] >= 0
    assert memory["peak_over_particles"] >= 1.0  # the state itself is resident throughout
    plane = results["table2_2d"]  # as many particles as the 3D block (64), 4 per cell: 4^2 cells
    assert plane["setup"]["dim"] == 2 and plane["setup"]["cells_per_side"] == 4 and plane["setup"]["particles"] == 64
    assert {(t["method"], t["stage"]) for t in plane["timings"]} == stages and "memory" not in plane
    assert "Table 2 (2D)" in out and "Table 2 (3D)" in out

    throughput = results["throughput"]
    assert [c["case"] for c in throughput["cases"]] == ["mpm88", "fluid3d", "large2d"]
    for r in throughput["results"]:
        n = next(c["particles"] for c in throughput["cases"] if c["case"] == r["case"])
        assert r["particle_steps_per_s"] == pytest.approx(n * 1 / r["median_s"])
        assert r["vs_numpy"] == 1.0  # only the reference ran

    for text in ("Table 2", "MPM/MLS", "P2G", "G2P", "Peak memory", "Throughput", "large2d", "Stages", "Scaling"):
        assert text in out

    for r in results["stages"]["results"]:  # the stages run inside the timed steps: they cannot add up to more
        assert set(r["stages_s"]) >= {"prepare", "p2g", "grid_update", "g2p", "return_map"}
        assert sum(r["stages_s"].values()) <= r["step_s"]
    assert results["scaling"]["sizes"] == [] and results["scaling"]["threads"] == []  # compiled backends only
    assert results["domain"]["results"] == []  # compiled backends only

    cpic = results["cpic"]
    assert cpic["case"]["bodies"] == 3 and cpic["case"]["segments"] == 60 + 18 + 1 and cpic["goal"] == 1.5
    (record,) = cpic["results"]
    assert record["particles"] == cpic["case"]["particles"] and TIMING_KEYS <= set(record["coupled"])
    assert record["ratio"] == pytest.approx(record["coupled"]["median_s"] / record["plain"]["median_s"])
    assert {"cpic_contact", "p2g", "cpic_impulses", "grid_update", "cpic_g2p"} <= set(record["coupled_stages_s"])
    assert "CPIC: a step with 3 bodies" in out
    assert results["busy"]["results"] == []  # the Numba backend's threads only
    ledger = results["ledger"]
    assert [c["case"] for c in ledger["cases"]] == ["mpm88", "block2d"] and "Energy ledger" in out
    for r in ledger["results"]:
        assert TIMING_KEYS <= set(r["off"]) and TIMING_KEYS <= set(r["on"])
        assert r["ratio"] == pytest.approx(r["on"]["median_s"] / r["off"]["median_s"])
    assert "Goals" in out and len(results["goals"]) == len(goals({})) and all("met" in g for g in results["goals"])


def test_table2_ratios_divide_mpm_by_mls():
    def timings(mls_p2g):
        medians = {("mpm", "stress"): 1.0, ("mpm", "p2g"): 5.0, ("mpm", "g2p"): 4.0,
                   ("mls", "stress"): 1.0, ("mls", "p2g"): mls_p2g, ("mls", "g2p"): 2.0}
        return [{"backend": "numba", "threads": 2, "dtype": "float32", "method": m, "stage": s, "median_s": t}
                for (m, s), t in medians.items()]

    (ratio,) = table2_ratios(timings(3.0))
    counted = predicted_ratio(3, "p2g")  # the operation counts' ratio of the transfers alone
    assert ratio == {"backend": "numba", "threads": 2, "dtype": "float32", "p2g": 5.0 / 3.0, "g2p": 2.0,
                     "p2g_minus_stress": 2.0, "predicted_p2g": pytest.approx((1.0 + 2.0 * counted) / 3.0),
                     "predicted_g2p": predicted_ratio(3, "g2p")}
    assert table2_ratios(timings(0.9))[0]["p2g_minus_stress"] is None  # P2G below its stress: noise


def test_the_operation_counts_follow_the_kernels_per_node_work():
    """Per particle, the classic method adds to each of the S^d nodes the gradient weight (3D: 5 products) and
    d(2d - 1 + 1) operations of the force in P2G, 2d^2 of the velocity gradient in G2P; the particle arrays moved are
    the same for both methods, so the predicted time ratio is the operation ratio."""
    from mpmref.bench.opcount import S, axis_setup, counts

    for dim, gradient in ((2, 2), (3, 5)):
        c = counts(dim)
        extra_setup = dim * (axis_setup("mpm") - axis_setup("mls"))
        assert c[("p2g", "mpm")].flops - c[("p2g", "mls")].flops == (
            S**dim * (2 * dim * dim + gradient) + extra_setup - 2 * dim * dim)  # MLS folds dt Q into A once: 2d^2
        assert c[("g2p", "mpm")].flops - c[("g2p", "mls")].flops == (
            S**dim * (2 * dim * dim + gradient) + extra_setup - dim**3)  # MLS divides B by D in the F update: d^3
        assert c[("p2g", "mpm")].bytes == c[("p2g", "mls")].bytes and c[("g2p", "mpm")].bytes == c[("g2p", "mls")].bytes
    assert predicted_ratio(3, "p2g") == pytest.approx(1461 / 837)


def test_options_from_the_command_line():
    assert options_from_args(parse(["--vs", "taichi"])).sections == (
        "table2", "table2_2d", "throughput", "stages", "scaling", "domain", "cpic", "busy", "ledger", "peer")
    assert options_from_args(parse(["--only", "cpic"])).sections == ("cpic",)
    assert options_from_args(parse(["--only", "peer"])).sections == ("peer",)
    opts = options_from_args(parse(["--dtype", "f32", "--threads", "1,2,4", "--full"]))
    assert opts.dtypes == ("float32",) and opts.threads == (1, 2, 4) and opts.table2_cells == 100
    assert options_from_args(parse([])).table2_cells == 50
    for bad in (["--dtype", "f16"], ["--threads", "0"]):
        with pytest.raises(SystemExit):
            parse(bad)
    with pytest.raises(BackendError, match="unknown backend 'vulkan'"):  # the command line's exit status 2
        parse(["--backends", "numpy,vulkan"])


def test_a_yardstick_is_read_and_the_goals_compare_the_throughput_cases_with_it(tmp_path):
    """A hand-written program's JSON lines (the peers print one per run) against the throughput section's rates on
    the same dimension, particle count, threads and dtype; a line without the keys is refused."""
    from mpmref.bench.goals import goals_section

    path = tmp_path / "hand.jsonl"
    path.write_text('{"code": "hand-2d", "dim": 2, "n_particles": 32768, "threads": 2, "dtype": "f32", '
                    '"particle_steps_per_s": 4.0e7}\n')
    yardstick = options_from_args(parse(["--yardstick", str(path)])).yardstick
    throughput = {"cases": [{"case": "mpm88", "particles": 32768}],
                  "results": [{"case": "mpm88", "backend": "numba", "threads": t, "dtype": "float32",
                               "particle_steps_per_s": rate} for t, rate in ((1, 2.0e7), (2, 3.4e7))]}
    by_name = {g["name"]: g for g in goals_section({"throughput": throughput, "yardstick": list(yardstick)})}
    hand = by_name["mpm88 2 threads float32: mpmref / hand-written"]
    assert hand["figure"] == pytest.approx(0.85) and hand["met"] is True and "hand-2d" in hand["where"]
    assert by_name["fluid3d 2 threads float32: mpmref / hand-written"]["figure"] is None
    assert by_name["2 threads over 1, idle"]["figure"] == pytest.approx(1.7)
    path.write_text('{"dim": 2}\n')
    with pytest.raises(SystemExit):
        parse(["--yardstick", str(path)])


def test_the_sections_are_registered_once_and_the_cli_the_json_and_the_tables_follow(monkeypatch):
    """--only's choices, the default sections and the JSON keys are the registry's; the runner runs and renders
    the registered section (here a stand-in for cpic, so nothing is timed)."""
    from mpmref.bench import DEFAULT_SECTIONS, sections

    names = tuple(section.name for section in sections.SECTIONS)
    assert SECTIONS == names and len(set(names)) == len(names)
    assert DEFAULT_SECTIONS == tuple(section.name for section in sections.SECTIONS if section.default)
    assert {"peer", "async", "cuda", "startup"} <= set(names) - set(DEFAULT_SECTIONS)  # long, or need more than a CPU
    parser = argparse.ArgumentParser(prog="mpmref")
    bench = add_parser(parser.add_subparsers(dest="command"))
    assert tuple(next(a for a in bench._actions if a.dest == "only").choices) == names
    stand_in = sections.Section("cpic", lambda options, log: {"results": [], "ran": options.quick},
                                lambda section: f"stand-in table, quick {section['ran']}")
    monkeypatch.setitem(sections.BY_NAME, "cpic", stand_in)
    lines = []
    results = run_bench(BenchOptions(backends=("numpy",), threads=(1,), sections=("cpic",), quick=True),
                        log=lines.append, progress=lambda line: None)
    assert list(results) == ["schema", "created_utc", "environment", "options", *names, "yardstick", "goals"]
    assert results["cpic"] == {"results": [], "ran": True} and lines[0] == "stand-in table, quick True\n"
    assert all(results[name] is None for name in names if name != "cpic")


def test_too_many_threads_are_refused_before_any_work():
    numba = pytest.importorskip("numba")
    options = BenchOptions(backends=("numba",), threads=(1, numba.config.NUMBA_NUM_THREADS + 1),
                           sections=("throughput",), quick=True)
    started = []
    with pytest.raises(MpmrefError, match="NUMBA_NUM_THREADS"):
        run_bench(options, log=started.append, progress=started.append)
    assert started == []


def test_peer_without_taichi_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "taichi", None)
    monkeypatch.setitem(sys.modules, "mpmref.peers.taichi_mpm88", None)
    monkeypatch.delattr(mpmref.peers, "taichi_mpm88", raising=False)
    section = run_peer([], ("numpy",), (1,), 1, 1, log=lambda m: None)
    assert section["available"] is False and "pip install 'mpmref[bench]'" in section["message"]
    assert render_peer(section).startswith("Peer: not run.")


def test_clear_of_walls_sees_a_particle_in_the_floor_band():
    scene = mpm88_scene(count=64)
    x = sample_particles(scene).x
    assert clear_of_walls(scene, x)
    x[0, 1] = (scene.boundary.width + 0.4) * scene.grid.dx  # its stencil reaches node width - 1
    assert not clear_of_walls(scene, x)


# ------------------------------------------------------------------------------------------- peer
def corner_scene():
    """Fluid thrown into the lower-left corner: wall bands with Coulomb friction act from the first step."""
    return (SceneBuilder(dim=2, name="corner").grid(size=1.0, cells=128).method("mls")
            .material("water", "fluid", K=400.0, gamma=1.0, rho=1.0)
            .box("water", lower=[0.01, 0.01], upper=[0.3, 0.3], sampling="random", count=512, velocity=[-1.0, -0.5])
            .gravity([0.0, -9.8]).walls("separate", friction=0.4, width=3).time(dt=2e-4).build())


@pytest.mark.parametrize("scene", [mpm88_scene(count=512, dtype="float64"), corner_scene()], ids=["mpm88", "corner"])
def test_taichi_peer_matches_the_numpy_reference_particle_by_particle(scene):
    """Float64, 512 particles, 8 steps: every particle's x, v and J agree with the reference to round-off,
    in free flight (``mpm88``) and against walls with friction (``corner``).

    The per-step round-off of :mod:`mpmref.bench.peer`, doubled for two codes, holds particle by particle:
    positions within :func:`~mpmref.bench.peer.roundoff_bound`; velocities within ``2 N kappa eps V``
    (``kappa eps V`` per step, carried from step to step); ``J`` relative within ``2 N eps (2 + dt d |dC|)``
    where the velocity round-off gives ``C = B / D`` an error of at most ``kappa eps V reach / D``. A
    position difference changes a particle's velocity by about ``C_p`` times it, so differences may grow by
    ``exp(N dt max|C|)`` over the run (Gronwall); the bounds are multiplied by that factor, which is
    asserted to stay below 2 (the paths have not diverged).
    """
    taichi_mpm88 = pytest.importorskip("mpmref.peers.taichi_mpm88")
    steps = 8
    initial = sample_particles(scene)
    reference, dt = initial, scene.time.dt
    backend = make_backend("numpy", scene)
    for i in range(steps):
        reference = substep(backend, reference, dt, i * dt)
    taichi_mpm88.init(1, "float64")
    peer = taichi_mpm88.TaichiFluid(scene, initial)
    peer.run(steps)
    theirs = peer.state()

    d, dx, eps = scene.dim, scene.grid.dx, np.finfo(np.float64).eps
    kappa, reach, inertia = 3 * 3**d + 3, 1.5 * np.sqrt(d) * dx, 0.25 * dx**2
    growth = np.exp(steps * dt * max(frobenius_max(reference.C), frobenius_max(theirs["C"])))
    assert growth < 2.0
    speed = max(np.abs(s["v"]).max() + reach * frobenius_max(s["C"]) for s in (reference.arrays(), theirs))
    bound_x = mean_position_bound(scene, [initial.arrays(), reference.arrays(), theirs], steps)
    assert np.abs(theirs["x"] - reference.x).max() <= growth * bound_x
    assert np.abs(theirs["v"] - reference.v).max() <= growth * 2 * steps * kappa * eps * speed
    bound_J = 2 * steps * eps * (2 + dt * d * kappa * speed * reach / inertia)
    assert np.abs(theirs["J"] / reference.J - 1.0).max() <= growth * bound_J


def test_peer_section_reports_timings_and_centre_of_mass_agreement():
    pytest.importorskip("taichi")
    section = run_peer([ThroughputCase("mpm88", mpm88_scene, (512, 128))], ("numpy",), (1,), 1, 5, log=lambda m: None)
    assert section["available"] and section["dtype"] == "float32" and section["steps"] == 5
    (row,) = section["results"]
    assert row["backend"] == "numpy" and row["threads"] == 1 and row["particles"] == 512
    assert TIMING_KEYS <= set(row["mpmref"]) and TIMING_KEYS <= set(row["taichi"])
    assert row["free_flight"] and row["agree"] and row["mean_position_difference"] <= row["bound"]
    assert "mpm88" in render_peer(section)


def test_peer_refuses_scenes_it_does_not_implement():
    taichi_mpm88 = pytest.importorskip("mpmref.peers.taichi_mpm88")
    with pytest.raises(MpmrefError, match="one material of type 'fluid'"):
        taichi_mpm88.check_scene(table2_scene(2))


@pytest.mark.slow  # a fresh Numba cache compiles float32 kernels in 2D and 3D for it: 20 s of one core
def test_numba_stages_and_scaling_records_are_consistent():
    """The Numba backend computes the stress inside P2G: the stress line is the stage timed alone; the scaling
    figures are the timed rates inverted, and one thread's speed-up over itself is 1."""
    pytest.importorskip("numba")
    from mpmref.bench.stage_times import run_scaling, run_stages

    stages = run_stages([c for c in throughput_cases(quick=True) if c.name == "mpm88"], ("numba",), (1,),
                        ("float32",), 2, log=lambda m: None)
    record = stages["results"][0]
    assert record["stress_inside_p2g"] and "stress" not in record["stages_s"] and record["stress_alone_s"] > 0
    assert sum(record["stages_s"].values()) <= record["step_s"]
    scaling = run_scaling(("numba",), (1,), ("float32",), 1, 1, quick=True, log=lambda m: None)
    assert [r["particles"] for r in scaling["sizes"]] == [512, 2048, 8**3 // 4, 16**3 // 4]
    for r in scaling["sizes"]:
        assert r["ns_per_particle_step"] == pytest.approx(1e9 * r["median_s"] / r["particles"])
    assert [r["speedup_over_1"] for r in scaling["threads"]] == [1.0]


def test_cpic_bench_steps_the_same_sand_outside_the_ring_with_and_without_the_bodies():
    from mpmref.bench.cpic import bed_particles, wheel_bed_scene
    from mpmref.rigid.polyline import SAND_WHEEL

    coupled, plain = wheel_bed_scene(32), wheel_bed_scene(32, bodies=False)
    assert len(coupled.rigid_bodies) == 3 and plain.rigid_bodies == [] and plain.cpic is None
    assert coupled.rigid_bodies[1].welded_to == 0 and coupled.time.dt == plain.time.dt
    x = bed_particles(coupled).x
    np.testing.assert_array_equal(x, bed_particles(plain).x)
    radius = np.linalg.norm(x - SAND_WHEEL["center"], axis=1)
    assert radius.min() > SAND_WHEEL["ring_radius"] * np.cos(np.pi / SAND_WHEEL["ring_segments"])  # none inside


@pytest.mark.slow  # the section's 3D float32 kernels: a fresh compile of about 14 s of one core
@pytest.mark.parametrize("memory", [False, True])
def test_domain_section_puts_the_same_body_in_growing_domains(memory):
    """The same particles in every domain, the step time's ratio to the smallest domain's, and (in fresh
    processes) a peak resident memory at least the baseline after compiling."""
    pytest.importorskip("numba")
    from mpmref.bench.domain import render_domain, run_domain

    section = run_domain(("numba",), (1,), ("float32",), 1, 1, quick=True, memory=memory, log=lambda m: None)
    rows = section["results"]
    assert [r["cells"] for r in rows] == [8, 16] and {r["particles"] for r in rows} == {4**3 * 8}
    assert [r["nodes"] for r in rows] == [9**3, 17**3]
    assert rows[0]["step_over_smallest"] == 1.0
    for r in rows:
        assert r["step_s"] == pytest.approx(r["median_s"]) and r["step_over_smallest"] == pytest.approx(
            r["step_s"] / rows[0]["step_s"])
        if memory:
            assert r["peak_bytes"] >= r["baseline_bytes"] > 0
    assert "Domain size at a fixed body" in render_domain(section)


def test_goals_are_read_off_the_sections_with_their_direction():
    """Each goal takes its figure from the section that measures it (two threads, float32, Numba) and is met
    only on the right side of its bound; a goal whose section did not run has no figure and no verdict."""
    from mpmref.bench.goals import goals_section, render_goals

    ratio = {"backend": "numba", "threads": 2, "dtype": "float32", "p2g": 1.9, "g2p": 1.7}
    results = {"table2": {"ratios": [ratio], "memory": [{"backend": "numba", "dtype": "float32", "particles": 262144,
                                                          "peak_over_state": 1.4}]},
               "peer": {"results": [{"case": "mpm88", "threads": 2, "backend": "numba", "ratio": 2.4}]},
               "domain": {"results": [{"backend": "numba", "dtype": "float32", "threads": 2, "cells": c, "step_s": s,
                                       "peak_bytes": 1.8e8} for c, s in ((32, 1.0), (256, 1.6))]}}
    by_name = {g["name"]: g for g in goals_section(results)}
    assert by_name["mpm88 2 threads float32: mpmref / Taichi CPU"]["met"] is False  # 2.4 < 2.5
    assert by_name["fluid3d 2 threads float32: mpmref / Taichi CPU"]["met"] is None
    assert by_name["Table 2 3D P2G: classic MPM / MLS-MPM"]["met"] is True
    assert by_name["Table 2 3D G2P: classic MPM / MLS-MPM"]["met"] is False
    assert by_name["Table 2 2D P2G: classic MPM / MLS-MPM"]["figure"] is None
    assert by_name["peak memory / particle state"]["met"] is True  # 1.4 <= 1.5
    domain = by_name["256^3 domain / 32^3 domain, same body: step time"]
    assert domain["figure"] == pytest.approx(1.6) and domain["met"] is False
    assert by_name["256^3 domain: peak memory (MB)"]["met"] is True  # 180 MB
    table = render_goals(goals_section(results))
    assert "Goals" in table and table.count("\n") == len(by_name) + 1


def test_async_case_reports_updates_wall_times_and_the_cost_of_a_level_update():
    pytest.importorskip("numba")
    from mpmref.bench.asynchronous import render_async, time_case
    from mpmref.bench.goals import goals

    r = time_case("stork2d", 0.0005, "numba", 1, 1)
    a = r["async"]
    assert a["level_updates"] > 0 and a["updates"] >= a["own_updates"] > 0
    assert 0 < a["stages_s"] < a["stepping_s"] < a["times_s"][-1]
    assert a["stages_us_per_update"] > 0 and a["bookkeeping_us_per_update"] > 0
    assert r["wall_ratio"] == pytest.approx(r["sync"]["median_s"] / a["median_s"])
    # the accounting: ideal >= work ratio (ghosts only add updates), the efficiencies between the three ratios
    assert r["own_updates_ratio"] >= r["updates_ratio"] > 0
    assert r["ghost_efficiency"] == pytest.approx(r["updates_ratio"] / r["own_updates_ratio"])
    assert r["implementation_efficiency"] == pytest.approx(r["wall_ratio"] / r["updates_ratio"])
    assert r["cfl_wall_ratio"] == pytest.approx(r["sync_cfl"]["median_s"] / a["median_s"])
    assert 0 < r["sync_cfl"]["steps"] and r["one_level"]["levels"] == [round(np.log2(r["sync_dt"] / 1.6e-6))]
    assert r["one_level_overhead"] == pytest.approx(r["one_level"]["median_s"] / r["sync"]["median_s"])
    assert a["counts"]["ghost_candidates"] > 0 and a["counts"]["ticks"] > 0
    table = render_async({"results": [r]})
    assert "stork2d" in table and "Accounting" in table
    by_name = {g.name: g for g in goals({"async": {"results": [r]}})}
    goal = by_name["stork2d: sync at the finest async step / async, wall time"]
    assert goal.figure == r["wall_ratio"] and goal.bound == 1.5 and "CFL step" in goal.where
    control = by_name["stork2d: one-level control / sync, time, |ratio - 1|"]
    assert control.figure == pytest.approx(abs(r["one_level_overhead"] - 1.0)) and control.at_most
    assert by_name["stork2d-256: async efficiency, wall ratio / update ratio"].figure is None  # not run here


def test_async_case_runs_its_configurations_in_rounds(monkeypatch):
    """The timed runs of a case alternate configuration by configuration, round after round, each warmed up once
    first: a change of load during the case weighs on every configuration alike. The other configurations are
    made from the first run's simulation (the finest step it took)."""
    from mpmref.bench import asynchronous

    order = []

    def stepping(scene, backend):
        order.append(scene)
        return float(len(order)), scene

    monkeypatch.setattr(asynchronous, "stepping", stepping)
    runs = asynchronous.in_rounds(lambda t: ("a", t), lambda sim: {"s": lambda t: ("s", t, sim)}, 1.0, "numba", 3)
    first_run = ("a", 1.0)
    assert order == [("a", 0.1), first_run, ("s", 0.1, first_run),
                     ("s", 1.0, first_run), ("a", 1.0), ("s", 1.0, first_run), ("a", 1.0), ("s", 1.0, first_run)]
    assert runs["first"][0]["times_s"] == [2.0, 5.0, 7.0] and runs["s"][0]["times_s"] == [4.0, 6.0, 8.0]
    assert runs["first"][0]["first_call_s"] == 1.0 and runs["s"][0]["median_s"] == 6.0


def test_busy_section_times_one_and_two_threads_with_and_without_a_busy_core():
    """Each run a process of its own (the trap shows only there): medians of the runs, the ratio two over one, the
    threading layer, and the goal read off the busy row. The figures are not judged here (benchmarks, not tests)."""
    from mpmref.bench.busy import render_busy, run_busy
    from mpmref.bench.goals import goals_section

    section = run_busy(quick=True, backends=("numba",), repeats=1, log=lambda line: None)
    assert section["steps"] == 10 and section["particles"] == 8192 and section["threading_layer"]
    assert [r["load"] for r in section["results"]] == ["as it is", "one core busy"]
    for r in section["results"]:
        assert all(len(r["times_s"][k]) == 1 and r["median_s"][k] > 0 for k in ("1", "2"))
        assert r["ratio"] == pytest.approx(r["median_s"]["2"] / r["median_s"]["1"])
    goal = next(g for g in goals_section({"busy": section}) if "one core busy" in g["name"])
    assert goal["figure"] == section["results"][1]["ratio"] and goal["bound"] == 1.3 and goal["at_most"]
    assert "one core busy" in render_busy(section)


def test_ledger_section_times_the_same_steps_with_the_ledger_off_and_on():
    """Off is the plain step (no ledger given), on a fresh ledger observing the same steps from the same particles:
    both end in the same state to round-off (the ledger changes nothing the stages compute, but it needs the force
    apart, so its steps run the unfused P2G: the same sums in another order), and the section reports both
    timings and their ratio. The figures are not judged here (benchmarks, not tests)."""
    from mpmref.bench.ledger import booked_steps, ledger_cases, render_ledger, run_ledger
    from mpmref.observe.ledger import EnergyLedger

    for scene, particles in ledger_cases(quick=True).values():
        backend = make_backend("numpy", scene)
        off = booked_steps(backend, particles.copy(), scene.time.dt, 2)
        ledger = EnergyLedger(scene)
        on = booked_steps(backend, particles.copy(), scene.time.dt, 2, ledger)
        assert relative_error(off.x, on.x) < 1e-13 and relative_error(off.v, on.v) < 1e-12 and ledger.last is not None
    section = run_ledger(quick=True, backends=("numpy",), threads=(1,), repeats=1, steps=1, log=lambda line: None)
    assert [(r["case"], r["backend"], r["threads"]) for r in section["results"]] == [("mpm88", "numpy", 1),
                                                                                    ("block2d", "numpy", 1)]
    assert "on/off" in render_ledger(section)


def test_the_startup_goals_are_the_wall_ratios_of_a_first_run_and_a_first_verify():
    """Issue "The first minute": a first run of mpm88 at most half the older commit's wall time, a first
    ``verify --quick`` at most 0.6 of it; the ratio is the startup section's (medians), read with its direction."""
    from mpmref.bench.goals import goals_section

    def row(command, this, against):
        return {"command": command, "this": [{"wall_s": t} for t in this],
                "against": [{"wall_s": t} for t in against], "ratio": sorted(this)[1] / sorted(against)[1]}

    section = {"this": "abc1234", "against": "11a2006",
               "rows": [row("run mpm88 (10 steps, numba)", [9.0, 12.0, 11.0], [24.0, 22.0, 30.0]),
                        row("verify --quick", [120.0, 100.0, 110.0], [150.0, 160.0, 170.0])]}
    by_name = {g["name"]: g for g in goals_section({"startup": section})}
    first_run = by_name["run mpm88 (10 steps, numba), cold: wall / older commit's"]
    assert first_run["figure"] == pytest.approx(11.0 / 24.0) and first_run["at_most"] and first_run["met"] is True
    assert first_run["where"] == "abc1234: 11.0 s, 11a2006: 24.0 s, median of 3"
    verify = by_name["verify --quick, cold: wall / older commit's"]
    assert verify["figure"] == pytest.approx(110.0 / 160.0) and verify["met"] is False  # 0.69 > 0.6
    assert goals_section({})[0]["met"] is None and by_name.keys() == {g["name"] for g in goals_section({})}
