"""A run whose backend keeps the particles in its own memory (mpmref.backends.residency) gives what a host run
gives: the same bits, the same errors and last good state, the same ledger, outputs and checkpoints, without ever
reading the particles where they live. Checked on the CPU with a stand-in "device": the reference's stages behind
arrays that refuse NumPy (any host code that touched them would fail), and a summary computed as the GPU backend's
kernel reduces it. The GPU backend's own refusals and its message without a GPU are here too."""

import numpy as np
import pytest

from mpmref import DomainExitError, NonFiniteError, SceneBuilder, Simulation
from mpmref.backends import BACKENDS, BUILTIN, DEVICE_BACKENDS, available, make_backend, residency
from mpmref.backends.cuda import CudaBackend
from mpmref.backends.numpy import NumpyBackend
from mpmref.cli import main
from mpmref.errors import BackendError, NotImplementedByBackend
from mpmref.scene import Scene
from mpmref.state import GridState, Particles
from mpmref.steppers.limits import signal_speeds


class Remote:
    """An array in another memory: it has a shape and a dtype and can be copied back, nothing else."""

    __array_ufunc__ = None  # NumPy refuses to compute with it

    def __init__(self, array):
        self._array = np.array(array)
        self.shape, self.dtype = self._array.shape, self._array.dtype

    def copy_to_host(self):
        return self._array.copy()

    def __array__(self, *args, **kwargs):
        raise TypeError("a remote array was read on the host")


def host_of(array):
    return array.copy_to_host() if isinstance(array, Remote) else array


class RemoteBackend:
    """The NumPy reference's stages, its particles and grid states in :class:`Remote` arrays (a resident backend
    that declares what the GPU backend declares)."""

    name = "remote"
    implements = CudaBackend.implements

    def __init__(self, scene):
        self.scene, self.reference = scene, NumpyBackend(scene)
        self.running = self.reference.running
        self.summaries = 0

    # residency
    def to_device(self, particles):
        return Particles(**{k: a if k == "id" else Remote(a) for k, a in particles.arrays().items()})

    def to_host(self, particles):
        return Particles(**{k: host_of(a) for k, a in particles.arrays().items()})

    @staticmethod
    def host_array(array):
        return host_of(array)

    def summarize(self, particles, previous=None):
        self.summaries += 1
        p = self.to_host(particles)
        old = p.v if previous is None else self.to_host(previous).v
        bad = tuple(k for k in ("x", "v", "C", "F", "J", "Jp", "modes")
                    if getattr(p, k) is not None and not np.isfinite(getattr(p, k)).all())
        speed = signal_speeds(self.scene.material_list, p)
        return residency.Summary(bad, p.x.min(axis=0, initial=np.inf), p.x.max(axis=0, initial=-np.inf),
                                 float(np.abs(p.v - old).max(initial=0.0)), float(speed.max(initial=0.0)))

    # stages: what comes in goes out (remote in, remote out)
    def _run(self, stage, particles, *args, **kwargs):
        remote = isinstance(particles.x, Remote)
        out = getattr(self.reference, stage)(self.to_host(particles), *args, **kwargs)
        return self.to_device(out) if remote and isinstance(out, Particles) else out

    def prepare(self, particles):
        return None

    def stress(self, particles):
        return self.reference.stress(self.to_host(particles))

    def p2g(self, particles, prepared=None, contact=None, classes=None):
        return self._grid(particles, self.reference.p2g(self.to_host(particles)))

    def p2g_fused(self, particles, dt, prepared=None):
        return self._grid(particles, self.reference.p2g_fused(self.to_host(particles), dt))

    @staticmethod
    def _grid(particles, gs):
        if not isinstance(particles.x, Remote):
            return gs
        return GridState(**{k: Remote(a) for k, a in gs.node_arrays().items()})

    def grid_update(self, grid_state, dt, time=0.0):
        host = GridState(**{k: host_of(a) for k, a in grid_state.node_arrays().items()})
        v, v_tilde = self.reference.grid_update(host, dt, time)
        if not isinstance(grid_state.mass, Remote):
            return v, v_tilde
        return Remote(v), None if v_tilde is None else Remote(v_tilde)

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        return self._run("g2p", particles, host_of(v_grid), None if v_tilde is None else host_of(v_tilde), dt)

    def return_map(self, particles):
        return self._run("return_map", particles)


def jelly(dt=None, exit_policy="error", ledger=False, steps=12, loner=(0.0, 0.0), walls="separate", law="snow"):
    b = (SceneBuilder(dim=2, name="remote").grid(size=1.0, cells=16).method("mls")
         .material("jelly", law, E=1e3, nu=0.3, rho=1.0)
         .box("jelly", lower=[0.3, 0.3], upper=[0.5, 0.5], angular_velocity=1.0)
         .points("jelly", [[0.85, 0.85]], velocity=list(loner))
         .gravity([0.0, -9.8]).walls(walls, friction=0.2, domain_exit=exit_policy)
         .output(every=4, energy_ledger=ledger))
    b.time(**({"dt": dt} if dt else {"cfl": 0.4}), steps=steps)
    return b.build()


@pytest.mark.parametrize("options", [{}, {"dt": 1e-3}, {"ledger": True, "dt": 1e-3}])
def test_a_resident_run_gives_the_host_runs_bits(tmp_path, options):
    scene = jelly(**options)
    host = Simulation(scene, backend="numpy", out_dir=tmp_path / "host")
    remote = Simulation(scene, backend=RemoteBackend, out_dir=tmp_path / "remote")
    assert remote.resident and not host.resident
    host.run()
    remote.run()
    assert remote.backend.summaries >= scene.time.steps  # each step checked by the backend's summary
    for name, a in host.particles.arrays().items():
        assert np.array_equal(a, remote.particles.arrays()[name]), name
    assert remote.time == host.time and remote.step_count == host.step_count
    assert (tmp_path / "host/diagnostics.csv").read_text() == (tmp_path / "remote/diagnostics.csv").read_text()
    resumed = Simulation.resume(scene, tmp_path / "remote", backend=RemoteBackend)
    assert resumed.resident and np.array_equal(resumed.x, remote.x)


def test_emitters_release_into_a_resident_run():
    data = jelly(dt=1e-3, steps=8).source
    data["emitters"] = [{"material": "jelly", "center": [0.7, 0.6], "radius": 0.02, "velocity": [-10.0, 0.0],
                         "start": 0.002, "interval": 0.004, "until": 0.01}]
    scene = Scene.from_dict(data)
    host, remote = Simulation(scene), Simulation(scene, backend=RemoteBackend)
    host.run()
    remote.run()
    assert remote.n_particles == host.n_particles > Simulation(scene).n_particles  # releases joined
    assert np.array_equal(remote.id, host.id) and np.array_equal(remote.x, host.x)


def test_assignment_reaches_a_resident_run():
    scene = jelly(dt=1e-3)
    host, remote = Simulation(scene), Simulation(scene, backend=RemoteBackend)
    for sim in (host, remote):
        sim.v = sim.v + 0.5  # a host copy changed, then assigned
        sim.run(steps=3)
    assert np.array_equal(host.x, remote.x) and np.array_equal(host.v, remote.v)


def test_a_resident_run_stops_as_a_host_run_does(tmp_path):
    # a particle leaving the domain: the summary sees it, the host check names it and saves the last good state
    scene = jelly(dt=1e-3, loner=(0.0, 8.0), walls="open", steps=40)
    results = {}
    for backend in ("numpy", RemoteBackend):
        sim = Simulation(scene, backend=backend, out_dir=tmp_path / str(backend)[-8:])
        with pytest.raises(DomainExitError) as caught:
            sim.run()
        results[backend] = (str(caught.value).split(";")[0], sim.step_count, sim.x.copy())
    (m1, s1, x1), (m2, s2, x2) = results.values()
    assert m1 == m2 and s1 == s2 and np.array_equal(x1, x2)


@pytest.mark.filterwarnings("ignore:invalid value encountered")
def test_a_resident_run_catches_non_finite_values():
    sim = Simulation(jelly(dt=1e-3, law="neo_hookean"), backend=RemoteBackend)
    sim.run(steps=2)
    sim.v = np.where(np.arange(sim.n_particles)[:, None] == 5, np.nan, sim.v)
    with pytest.raises(NonFiniteError, match="non-finite"):
        sim.run(steps=1)
    assert sim.step_count == 2  # the last good state stays


def test_host_backends_are_not_resident():
    scene = jelly(dt=1e-3)
    for name in BACKENDS:
        assert not residency.resident(make_backend(name, scene))
        assert not Simulation(scene, backend=name).resident


# ----------------------------------------------------------------------------------------- the GPU backend
def example(name):
    return Scene.from_toml(f"examples/{name}.toml")


def test_cuda_is_a_built_in_name_apart_from_the_cpu_backends():
    assert DEVICE_BACKENDS == ("cuda",) and "cuda" in BUILTIN and "cuda" in available()
    assert "cuda" not in BACKENDS  # the CPU tests and benchmarks run on every machine


@pytest.mark.parametrize("name, missing", [("stork2d", "asynchronous time stepping"),
                                           ("cut2d", "rigid bodies")])
def test_cuda_refuses_what_it_does_not_implement_before_any_work(name, missing):
    with pytest.raises(NotImplementedByBackend, match=missing):
        make_backend("cuda", example(name))


def _gpu_usable():
    try:
        from mpmref.backends.cuda.runtime import require_device

        require_device()
    except BackendError:
        return False
    return True


@pytest.mark.skipif(_gpu_usable(), reason="a GPU is usable here: the message without one cannot be shown")
def test_cuda_without_a_gpu_is_one_line_and_exit_status_2(tmp_path, capsys):
    assert main(["run", "examples/mpm88.toml", "--backend", "cuda", "--steps", "1", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cuda" in err and ("GPU" in err or "numba-cuda" in err)
    assert not any(tmp_path.iterdir())  # refused before any work


def test_cuda_without_numba_cuda_names_the_package(monkeypatch):
    from types import SimpleNamespace

    from mpmref.backends.cuda import runtime

    monkeypatch.setattr(runtime, "cuda", SimpleNamespace(implementation="Built-in"))
    with pytest.raises(BackendError, match=r"numba-cuda.*pip install -e '\.\[gpu\]'"):
        runtime.require_device()


@pytest.mark.skipif(_gpu_usable(), reason="a GPU is usable here: the bench section would run")
def test_the_bench_section_and_the_device_check_say_there_is_no_gpu(tmp_path):
    from mpmref.bench import BenchOptions
    from mpmref.bench.device_check import main as device_check
    from mpmref.bench.gpu import render_cuda, run_cuda

    section = run_cuda(BenchOptions(quick=True))
    assert section["available"] is False and "GPU" in section["message"]
    assert render_cuda(section).startswith("cuda: not run (")
    assert device_check(["--out", str(tmp_path)]) == 2
    assert '"available": false' in (tmp_path / "device_check.jsonl").read_text()
