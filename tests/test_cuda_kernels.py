"""The GPU backend checked where there is no GPU (this machine, CI).

* Every kernel is compiled for the H100 (compute capability 9.0) by numba-cuda's compiler
  (``numba.cuda.compile_ptx``): that types every kernel and device function, which the simulator does not. The
  default suite compiles two representative configurations (each takes seconds to compile); the slow set compiles
  every configuration of the conformance harness, both dtypes (56 each, about ten minutes on two cores).
* The stages run in numba-cuda's simulator (``NUMBA_ENABLE_CUDASIM=1``, which must be set before Numba is imported:
  a subprocess) on the conformance harness's own cases, compared with the NumPy reference at its tolerances; and a
  resident run against the reference, twice (the same bits), and with the atomic P2G. The simulator runs each CUDA
  thread as a Python thread, so only tiny cases: a handful by default, every 2D case and a sample of 3D ones in the
  slow set. What needs a real GPU (timings, the whole harness at full speed, run-to-run determinism under real
  scheduling, the atomic mode's varying bits) is the device check's: ``python -m mpmref.bench.device_check``
  (docs/gpu.md).

The simulator needs numba-cuda alone, which the ``test`` extra installs; compiling for the device needs CUDA's
compiler library NVVM too, which the ``gpu`` extra brings (``pip install -e '.[test,gpu]'``, as ``.ci/run`` does for
the slow set) or a CUDA toolkit installed on the machine. Each group is skipped, with one line saying what is
missing, where its part is not installed.
"""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mpmref.conformance import make_cases

ROOT = Path(__file__).resolve().parent.parent


def _numba_cuda_missing():
    """Why numba-cuda cannot run its simulator here, or ``None``."""
    try:
        from mpmref.backends.cuda.runtime import load

        load()
    except Exception as exc:  # ImportError, BackendError: reported as the skip's reason
        return f"numba-cuda is not usable here ({type(exc).__name__}: {exc})"
    return None


def _compiler_missing():
    """Why numba-cuda cannot compile for a device here (no NVVM, or no NVRTC, which it asks for the compute
    capabilities it can target), or ``None``."""
    try:
        from numba.cuda.cudadrv.nvrtc import get_supported_ccs
        from numba.cuda.cudadrv.nvvm import NVVM

        NVVM()
        get_supported_ccs()
    except Exception as exc:  # NvvmSupportError, DynamicLibNotFoundError and the like: reported as the skip's reason
        return (f"CUDA's compiler libraries NVVM and NVRTC are not both installed ({type(exc).__name__}); "
                "pip install -e '.[gpu]' brings them")
    return None


MISSING = _numba_cuda_missing()
pytestmark = pytest.mark.skipif(MISSING is not None, reason=MISSING or "")
NO_COMPILER = MISSING or _compiler_missing()
#: the tests that compile for the device: skipped where NVVM is missing, the simulator's still run
compiles = pytest.mark.skipif(NO_COMPILER is not None, reason=NO_COMPILER or "")

#: the representative set of the default suite, named by a conformance case of each configuration and the kernels
#: compiled of it: every kernel of the benchmarks' fluid (2D, float32, MLS-MPM, the fused and plain P2G, gather and
#: atomic), and every material law in 3D (float64: the 3D SVD, both return maps); the slow set compiles every
#: configuration of the harness
REPRESENTATIVE = {"step-2d-mls-mls-quadratic-f32": "", "step-3d-mixed": "particles."}

def _cases(names):
    by_name = {c.name: c for dtype in ("float64", "float32") for c in make_cases(dtype=dtype)}
    return [by_name[n] for n in names]


def _compile(cases, prefix=""):
    """Every kernel of the cases' configurations whose name starts with ``prefix``, once each, for CC 9.0:
    ``{kernel: ptx}``."""
    from mpmref.backends.cuda.kernels import Config, Kernels

    done = {}
    for config in dict.fromkeys(Config.of(c.scene()) for c in cases):
        for name, kernel in Kernels(config).all(fused=True, atomic=True).items():
            if id(kernel) not in done and name.startswith(prefix):
                done[id(kernel)] = (f"{config.dtype}/{config.dim}d/{name}", kernel.ptx((9, 0)))
    return dict(done.values())


#: float64 arithmetic in PTX (loads and conversions of float64 arguments are not arithmetic)
DOUBLE_ARITHMETIC = re.compile(r"^\s*(add|sub|mul|fma|div|sqrt|neg|abs|min|max|rcp|setp\.\w+)\S*\.f64", re.M)


@compiles
def test_representative_kernels_compile_for_the_h100():
    """Every kernel of the representative set compiles for CC 9.0, and the float32 ones do no float64 arithmetic (the
    pointwise functions take the run's type; a float literal would promote them), but the summary and the return map's
    wave speeds (its output ``wave_speed``), whose wave speeds are float64 as the reference's."""
    ptx = {}
    for case, prefix in REPRESENTATIVE.items():
        ptx |= _compile(_cases([case]), prefix)
    assert len(ptx) == 24  # one grid update serves the plain and the fused P2G
    for name, text in ptx.items():
        assert ".target sm_90" in text and ".entry" in text, name
    doubled = {name: len(DOUBLE_ARITHMETIC.findall(text)) for name, text in ptx.items()
               if name.startswith("float32/") and not name.endswith(("particles.summarize", "particles.wave_speeds"))}
    assert len(doubled) > 15 and {name: n for name, n in doubled.items() if n} == {}


@pytest.mark.slow
@compiles
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_every_kernel_of_the_harness_compiles_for_the_h100(dtype):
    ptx = _compile(make_cases(dtype=dtype))
    assert all(".target sm_90" in text for text in ptx.values())


# ---------------------------------------------------------------------------------------------- simulator
SIMULATED = r'''
import json, sys
import numpy as np
from mpmref import Scene, Simulation
from mpmref.conformance import check, make_cases
from mpmref.steppers.pipeline import substep

names = set(json.loads(sys.argv[1]))
cases = [c for dtype in ("float64", "float32") for c in make_cases(dtype=dtype) if c.name in names]
report = check("cuda", cases, progress=False)
out = {"cases": {r.case.name: [r.error, r.rtol, r.note] for r in report.results}}
if json.loads(sys.argv[2]):
    scene = Scene.from_dict({
        "name": "tiny", "dim": 2, "gravity": [0.0, -9.8], "grid": {"size": [1.0, 1.0], "cells": 10},
        "method": {"scheme": "mls"},
        "materials": {"jelly": {"type": "snow", "E": 5000.0, "nu": 0.3, "rho": 1.0},
                      "water": {"type": "fluid", "K": 400.0, "gamma": 7.0, "rho": 1.0}},
        "bodies": [{"shape": "box", "material": "jelly", "lower": [0.3, 0.3], "upper": [0.5, 0.5], "ppc": 4,
                    "angular_velocity": 2.0},
                   {"shape": "box", "material": "water", "lower": [0.55, 0.3], "upper": [0.7, 0.45], "ppc": 4}],
        "colliders": [{"shape": "disk", "type": "separate", "friction": 0.3, "center": [0.4, 0.2], "radius": 0.1,
                       "velocity": [0.0, 1.0]}],
        "boundary": {"type": "separate", "friction": 0.5, "width": 3}, "time": {"cfl": 0.5, "steps": 3}})
    runs = []
    for backend in ("numpy", "cuda", "cuda"):
        sim = Simulation(scene, backend=backend)
        sim.run()
        runs.append((sim.resident, sim.x, sim.v, sim.F, sim.particles.Jp, sim.time))
    (_, x0, v0, F0, J0, t0), (resident, x1, v1, F1, J1, t1), (_, x2, v2, F2, J2, t2) = runs
    speed = np.abs(v0).max()
    out["run"] = {"resident": resident, "x": float(np.abs(x1 - x0).max() / scene.grid.dx),
                  "v": float(np.abs(v1 - v0).max() / speed), "F": float(np.abs(F1 - F0).max()),
                  "Jp": float(np.abs(J1 - J0).max()), "time": abs(t1 - t0) / t0,
                  "same_bits": all(np.array_equal(a, b) for a, b in ((x1, x2), (v1, v2), (F1, F2), (J1, J2)))}
    start = Simulation(scene).particles
    gather = Simulation(scene, backend="cuda").backend
    atomic = Simulation(scene, backend="mpmref.backends.cuda:atomic").backend
    a, b = (be.to_host(substep(be, be.to_device(start), 1e-3, 0.0)) for be in (gather, atomic))
    out["atomic"] = float(np.abs(a.v - b.v).max() / np.abs(a.v).max())
print("RESULT " + json.dumps(out))
'''


def simulate(names, run=False):
    """Run ``names`` (conformance cases) and, with ``run``, the resident runs, in numba-cuda's simulator."""
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1"}
    done = subprocess.run([sys.executable, "-c", SIMULATED, json.dumps(list(names)), json.dumps(run)], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=3600)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    assert done.returncode == 0 and lines, done.stderr[-3000:]
    return json.loads(lines[-1][len("RESULT "):])


#: a handful of the harness's cases for the default suite: every stage, both dtypes, both dimensions
FEW = ("stress-2d-mixed", "return_map-2d-mixed", "grid_update-2d-mixed", "grid_update-3d-colliders",
       "p2g-2d-polypic-classic-cubic", "p2g_fused-2d-pic-classic-linear", "g2p-2d-flip-mls-quadratic",
       "step-2d-mixed", "ledger-2d-colliders", "step-2d-apic-classic-quadratic-f32", "stress-3d-mixed",
       "return_map-3d-mixed-f32")


def test_stages_in_the_simulator_match_the_reference():
    out = simulate(FEW, run=True)
    assert set(out["cases"]) == set(FEW)
    for name, (error, rtol, note) in out["cases"].items():
        assert error <= rtol, (name, error, note)
    run = out["run"]
    assert run["resident"]
    # three steps of a spinning snow block and a fluid on a moving collider: the two codes differ by the order of
    # their sums only, a few ulps carried three steps (the conformance bound, 1e-12, per step)
    assert run["x"] < 1e-12 and run["v"] < 1e-12 and run["F"] < 1e-12 and run["Jp"] < 1e-12 and run["time"] < 1e-12
    assert run["same_bits"]
    assert out["atomic"] < 1e-12  # the atomic P2G sums in another order: the same to round-off


@pytest.mark.slow
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_every_2d_case_and_a_3d_sample_in_the_simulator(dtype):
    cases = [c.name for c in make_cases(dims=(2,), dtype=dtype)]
    cases += [c.name for c in make_cases(dims=(3,), dtype=dtype)
              if c.stage in ("stress", "return_map", "grid_update") or c.name.split("-3d-")[1].startswith("mls-")]
    out = simulate(cases)
    failed = {n: v for n, v in out["cases"].items() if not v[0] <= v[1]}
    assert len(out["cases"]) == len(cases) and not failed, failed


DEVICE_CHECK = r'''
import sys
from mpmref.bench import device_check as dc, gpu
from mpmref import Scene
dc.DETERMINISM = (64, 8, 3)
gpu.MIN_TIME = 0.01
dc.conformance_chunks = lambda workers: [(["stress-2d-mixed", "step-2d-fluid"], "float64"),
                                         (["grid_update-2d-mixed-f32"], "float32")]
scene = Scene.from_dict({"name": "tiny", "dim": 2, "grid": {"size": [1.0, 1.0], "cells": 8},
                         "materials": {"w": {"type": "fluid", "K": 400.0, "gamma": 1.0, "rho": 1.0}},
                         "bodies": [{"shape": "box", "material": "w", "lower": [0.4, 0.4], "upper": [0.6, 0.6]}],
                         "gravity": [0.0, -9.8], "time": {"dt": 1e-3}})
dc.trajectory_scenes = lambda: [("tiny", scene, 2)]
sys.exit(dc.main(["--workers", "2", "--skip", "verify", "--sizes", "2:64:8", "--out", sys.argv[1]]))
'''


@pytest.mark.slow
def test_the_device_check_runs_in_the_simulator(tmp_path):
    """The device check's parts, shrunk to the simulator's size (the harness to three cases, the runs to a few
    steps of a few particles): every line it prints, and exit status 0."""
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1"}
    done = subprocess.run([sys.executable, "-c", DEVICE_CHECK, str(tmp_path)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=3600)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = [json.loads(line) for line in (tmp_path / "device_check.jsonl").read_text().splitlines()]
    checks = [line["check"] for line in lines]
    assert checks[0] == "environment" and checks[-1] == "done" and lines[-1]["passed"]
    assert {"conformance", "trajectory", "determinism", "bench", "goal"} <= set(checks)
    assert all(line["identical"] for line in lines if line["check"] == "determinism" and line["p2g"] == "gather")


def test_the_summary_flags_the_fields_a_step_evolves_in_their_declared_order():
    """``CHECKED_FIELDS`` is the state's own list of evolving fields, and the kernel that flags them takes them in
    that order (``v_old`` beside ``v`` is the velocity before the step, for the largest change)."""
    import inspect

    from mpmref.backends.cuda.particles import CHECKED_FIELDS, particle_kernels
    from mpmref.backends.pointwise.laws import laws_of
    from mpmref.physics.materials import FixedCorotated
    from mpmref.state import EVOLVING_FIELDS

    kernels = particle_kernels("float64", 2, laws_of([FixedCorotated(E=1.0)])[0])
    names = [n for n in inspect.signature(kernels.summarize.fn).parameters if n != "v_old"]
    assert CHECKED_FIELDS == EVOLVING_FIELDS and tuple(names[:len(CHECKED_FIELDS)]) == CHECKED_FIELDS
