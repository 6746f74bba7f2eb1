"""``mpmref compare``: the statistics, the two tests of the verdict against their theory, and whole comparisons of
mpmref's own output (verification/compare/; docs/comparing_runs.md)."""

import json

import meshio
import numpy as np
import pytest
from scipy import stats as distributions

from mpmref import Scene, Simulation
from mpmref.cli import main
from mpmref.physics.materials import FixedCorotated, WeaklyCompressibleFluid
from verification.compare import compare
from verification.compare.comparison import Measures, frame_stops
from verification.compare.ensemble import PERTURBATION_ULPS, perturbed
from verification.compare.report import write_report
from verification.compare.statistics import material_statistics
from verification.compare.verdict import PARTICLE_FACTOR, FrameLabel, hotelling, judge, standardised, z_limit
from verification.framework.executor import Executor

SCENE = """
name = "drop"
dim = {dim}
gravity = {gravity}
[grid]
size = 1.0
cells = 16
[method]
scheme = "mls"
[materials.jelly]
type = "fixed_corotated"
E = 300.0
nu = 0.3
rho = 1.0
[materials.water]
type = "fluid"
K = 30.0
gamma = 7.0
rho = 1.0
[[bodies]]
shape = "box"
material = "jelly"
lower = {jelly_lower}
upper = {jelly_upper}
ppc = {ppc}
velocity = {velocity}
[[bodies]]
shape = "box"
material = "water"
lower = {water_lower}
upper = {water_upper}
ppc = {ppc}
[boundary]
type = "separate"
friction = 0.3
width = 2
[time]
dt = 5e-4
steps = 120
[output]
every = 20
"""


def scene_text(dim):
    pad = [0.3] * (dim - 2)
    return SCENE.format(dim=dim, gravity=[0.0, -9.8] + [0.0] * (dim - 2), ppc=4 if dim == 2 else 1,
                        jelly_lower=[0.2, 0.3] + pad, jelly_upper=[0.45, 0.5] + [0.5] * (dim - 2),
                        velocity=[1.0, -1.5] + [0.0] * (dim - 2),
                        water_lower=[0.55, 0.15] + pad, water_upper=[0.8, 0.4] + [0.5] * (dim - 2))


@pytest.fixture(scope="module")
def drop(tmp_path_factory):
    """The 2D scene file and the frames of its Numba and NumPy runs (mpmref run, .pvd series)."""
    folder = tmp_path_factory.mktemp("drop")
    path = folder / "drop.toml"
    path.write_text(scene_text(2))
    for backend in ("numba", "numpy"):
        assert main(["run", str(path), "--out", str(folder / backend), "--backend", backend, "--no-progress"]) == 0
    return path, folder


# ------------------------------------------------------------------------------------------------ statistics
def test_statistics_of_two_particles_by_hand():
    x = np.array([[0.25, 0.5], [0.75, 0.5]])
    v = np.array([[1.0, 0.0], [0.0, 2.0]])
    F = np.array([[[2.0, 0.0], [0.0, 1.0]], [[1.0, 0.5], [0.0, 1.0]]])
    mass = np.array([1.0, 3.0])
    s = material_statistics(x, {"v": v, "F": F}, mass, FixedCorotated(E=1.0), np.array([0.5, 0.5]))
    assert s["com_x"] == pytest.approx((0.25 + 3 * 0.75) / 4) and s["com_y"] == 0.5
    assert (s["momentum_x"], s["momentum_y"]) == (1.0, 6.0)
    assert s["angular_momentum"] == pytest.approx(1.0 * (-0.25 * 0.0 - 0.0 * 1.0) + 3.0 * (0.25 * 2.0 - 0.0))
    assert s["kinetic_energy"] == pytest.approx(0.5 * (1.0 + 3.0 * 4.0))
    assert (s["J_min"], s["J_max"], s["J_mean"]) == (1.0, 2.0, 1.5)
    assert (s["min_x"], s["max_x"], s["q50_x"]) == (0.25, 0.75, 0.5)
    fluid = material_statistics(x, {"J": np.array([0.9, 1.1])}, mass, WeaklyCompressibleFluid(K=1.0), np.zeros(2))
    assert fluid["J_mean"] == pytest.approx(1.0) and "momentum_x" not in fluid  # no velocity: no momentum


def test_members_start_a_few_ulps_off_the_control():
    x = np.random.default_rng(0).random((1000, 2)) + 0.5
    assert perturbed(x, 0, 5) is x
    for dtype in (np.float64, np.float32):
        y = perturbed(x.astype(dtype), 3, 5)
        ratio = np.abs(y.astype(np.float64) / x.astype(dtype) - 1.0) / np.finfo(dtype).eps
        assert y.dtype == dtype and 0 < ratio.max() <= PERTURBATION_ULPS + 1 and ratio.mean() > 0.5
        assert np.array_equal(perturbed(x.astype(dtype), 3, 5), y)  # seeded


# ------------------------------------------------------------------------------------------------ the tests
def correlated(rng, n, p):
    """``n`` samples of ``p`` correlated Gaussian statistics (a random mixing of fewer factors plus noise)."""
    mixing = rng.normal(size=(4, p))
    return lambda size: rng.normal(size=(size, 4)) @ mixing + 0.1 * rng.normal(size=(size, p))


def test_hotelling_false_alarms_match_fishers_distribution():
    """A run drawn from the ensemble's own Gaussian distribution fails the T^2 test with probability alpha."""
    rng = np.random.default_rng(1)
    draw, alpha, trials = correlated(rng, 21, 12), 0.1, 2000
    fails = 0
    for _ in range(trials):
        samples, new = draw(21), draw(1)[0]
        z_samples, z_new, _ = standardised(samples, new, np.zeros(12))
        t2, limit, k = hotelling(z_samples, z_new, alpha)
        fails += t2 > limit
    low, high = distributions.binom.interval(0.999, trials, alpha)
    assert low / 3 <= fails <= high  # at most alpha (keeping fewer components only lowers it), not absurdly below


def test_each_statistic_limit_bounds_false_alarms_and_a_shift_fails():
    rng = np.random.default_rng(2)
    draw, alpha, trials, p = correlated(rng, 21, 30), 0.05, 2000, 30
    limit = z_limit(21, p, alpha)
    fails = sum(np.abs(standardised(draw(21), draw(1)[0], np.zeros(p))[1]).max() > limit for _ in range(trials))
    assert fails <= distributions.binom.ppf(0.999, trials, alpha)  # Bonferroni: at most alpha, whatever the correlation
    samples = draw(21)
    shifted = samples.mean(axis=0) + 3 * limit * samples.std(axis=0, ddof=1) * (np.arange(p) == 7)
    z = standardised(samples, shifted, np.zeros(p))[1]
    assert np.argmax(np.abs(z)) == 7 and np.abs(z).max() > limit


def test_round_off_phase_ends_for_good_and_judges_particles():
    spreads = np.array([1e-15, 2e-15, 5e-12, 1e-15])  # the ensemble leaves round-off at frame 2
    deviations = np.array([0.0, 1.9e-14, 1e-9, 1e-9])
    samples = np.random.default_rng(3).normal(size=(4, 21, 5))
    code = samples.mean(axis=1)
    labels = [FrameLabel(k, None) for k in range(4)]

    def measures():
        return Measures(list("abcde"), samples, code, np.zeros(5), spreads, deviations, roundoff_limit=1e-12)

    verdicts = judge(labels, measures())
    assert [v.phase for v in verdicts] == ["round-off", "round-off", "ensemble", "ensemble"]
    assert [v.passed for v in verdicts] == [True, True, True, True]  # 1.9e-14 <= 10 x 2e-15; then statistics
    deviations[1] = 2.1e-14
    second = judge(labels, measures())[1]
    assert not second.passed and f"more than {PARTICLE_FACTOR:g} x" in second.reason()


# ------------------------------------------------------------------------------------------------ comparisons
def test_numba_and_numpy_output_pass_and_the_report_is_written(drop, tmp_path):
    path, folder = drop
    scene = Scene.from_toml(path)
    own = compare(scene, folder / "numba" / "particles.pvd", members=7, executor=Executor(workers=1))
    assert own.passed and own.measures.deviations.max() == 0.0  # the control is the same code: the same bits
    numpy = compare(scene, folder / "numpy", members=7, executor=Executor(workers=2))
    assert numpy.passed and 0.0 < numpy.measures.deviations.max() <= PARTICLE_FACTOR * numpy.measures.spreads.max()
    assert {v.phase for v in numpy.verdicts} == {"round-off"} and len(numpy.frames) == 7
    index = write_report(numpy, tmp_path)
    result = json.loads((tmp_path / "results.json").read_text())
    assert result["passed"] and result["first_failure"] is None and len(result["frames"]) == 7
    assert "water:kinetic_energy" in result["statistics"] and "jelly:J_min" in result["statistics"]
    assert index.read_text().count("<tr") == 8
    for name in ("deviation.png", "test.png", "statistics_jelly.png", "statistics_water.png"):
        assert (tmp_path / name).stat().st_size > 1000
    mesh = meshio.read(tmp_path / "deviation_000120.vtu")
    assert np.allclose(np.ravel(mesh.point_data["deviation"]), numpy.measures.particle_deviation[-1])


def test_a_code_that_departs_at_a_frame_is_named_there(drop, tmp_path):
    path, folder = drop
    scene = Scene.from_toml(path)
    frames = (tmp_path / "frames")
    frames.mkdir()
    sim = Simulation(scene)
    for k in range(0, 121, 20):
        sim.run(until_step=k)
        water = (sim.particles.material == 1)[:, None] * np.array([1.0, 0.0])
        x = sim.x + (1e-9 * water if k >= 60 else 0.0)  # the water shifted along x from step 60 on
        np.savez(frames / f"f_{k:03d}.npz", x=x, id=sim.id, v=sim.v)
    result = compare(scene, frames, members=7, executor=Executor(workers=1))
    failure = result.first_failure
    assert failure.step == 60 and failure.phase == "round-off" and failure.index == 3
    assert failure.left[0][0] in ("water:com_x", "water:q50_x", "water:q05_x", "water:q95_x", "water:min_x",
                                  "water:max_x") and failure.materials()[0] == "water"
    assert frame_stops(scene, result.frames) == tuple(("step", k) for k in range(0, 121, 20))


def test_three_dimensional_output_of_the_numba_backend_passes(tmp_path):
    path = tmp_path / "drop3d.toml"
    path.write_text(scene_text(3).replace("steps = 120", "steps = 40"))
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--backend", "numba", "--no-progress"]) == 0
    result = compare(Scene.from_toml(path), tmp_path / "run", members=7, executor=Executor(workers=1))
    assert result.passed and "water:angular_momentum_z" in result.measures.names and len(result.frames) == 3


def test_command_line_refuses_a_bad_frame_and_too_small_an_ensemble(drop, tmp_path, capsys):
    path, _ = drop
    (tmp_path / "f_0.npz").write_bytes(b"garbage")
    assert main(["compare", str(path), str(tmp_path), "--members", "7", "--no-progress"]) == 2
    assert "f_0.npz: cannot be read" in capsys.readouterr().err
    assert main(["compare", str(path), str(tmp_path), "--members", "3"]) == 2
    assert "argument --members: 3 is out of range; allowed: an integer >= 7" in capsys.readouterr().err


def test_members_run_on_a_dask_cluster_as_in_this_process(drop):
    from dask.distributed import LocalCluster

    path, folder = drop
    scene = Scene.from_toml(path)
    here = compare(scene, folder / "numpy", members=7, executor=Executor(workers=1))
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        there = compare(scene, folder / "numpy", members=7, executor=Executor(scheduler=cluster.scheduler_address))
    assert there.passed and "dask.distributed" in there.where
    assert np.array_equal(np.sort(there.measures.samples, axis=1), np.sort(here.measures.samples, axis=1))


def test_a_code_that_did_not_read_the_start_exactly_fails_at_step_0(drop, tmp_path):
    path, _ = drop
    scene = Scene.from_toml(path)
    sim = Simulation(scene)
    text = np.vectorize(lambda v: float(f"{v:.5g}"))  # a start read from text written with 5 significant digits
    np.savez(tmp_path / "f_0.npz", x=text(sim.x), id=sim.id)
    failure = compare(scene, tmp_path, members=7, executor=Executor(workers=1)).first_failure
    assert failure.step == 0 and "the code did not start from the exported start" in failure.reason()
