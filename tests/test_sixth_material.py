"""A material added outside the toolkit (tests/sixth_material.py: its reference class and its pointwise functions)
runs on both compiled backends with nothing written for it in either: the conformance harness compares their stress
and whole steps with the reference on it, on the Numba backend here and on the GPU backend in numba-cuda's simulator,
and its kernels compile for the device (compute capability 9.0).

What the test does write is the material's scene name: the catalogue of material types
(:data:`mpmref.physics.catalogue.MATERIALS`) and three copies of it made when their modules are imported (the
declarations' list of material types, :data:`mpmref.backends.capabilities.EVERYTHING`, and the reference's kernel
table) learn of it through :func:`register` — the vocabulary of scenes, not a table of either compiled backend.
"""

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from mpmref.conformance import check, make_cases
from mpmref.conformance.case import ConformanceCase

ROOT = Path(__file__).resolve().parent.parent
#: the stages checked on the new material, each on the built-in cases of the fixed-corotated solid
BASE_CASES = ("stress-2d-fixed_corotated", "stress-3d-fixed_corotated", "step-2d-fixed_corotated",
              "step-3d-fixed_corotated")
SPEC = {"E": 2.0e3, "nu": 0.3, "rho": 1.0}


def register():
    """The sixth material's scene name, in the catalogue and in what copies it at import; returns ``undo``."""
    from sixth_material import KIND, StVenantKirchhoff

    from mpmref.backends import capabilities
    from mpmref.backends.numpy import backend as reference
    from mpmref.physics.catalogue import MATERIALS
    from mpmref.physics.materials import FixedCorotated

    saved = (dict(capabilities._CHOICES), capabilities.EVERYTHING)
    MATERIALS[KIND] = StVenantKirchhoff
    capabilities._CHOICES["materials"] = tuple(MATERIALS)
    capabilities.EVERYTHING = capabilities.Implements(materials=tuple(MATERIALS))
    reference.MATERIAL_KERNELS[StVenantKirchhoff] = reference.MATERIAL_KERNELS[FixedCorotated]

    def undo():
        del MATERIALS[KIND], reference.MATERIAL_KERNELS[StVenantKirchhoff]
        capabilities._CHOICES.clear()
        capabilities._CHOICES.update(saved[0])
        capabilities.EVERYTHING = saved[1]

    return undo


def cases(dtype="float64"):
    """The built-in cases of :data:`BASE_CASES` with the sixth material in place of the fixed-corotated solid."""
    from sixth_material import KIND

    found = {c.name: c for c in make_cases(stages=("stress", "step"), dtype=dtype, materials=("fixed_corotated",))}
    out = []
    for name in BASE_CASES:
        base = found[name + ("-f32" if dtype == "float32" else "")]
        scene = json.loads(json.dumps(base.scene_dict))
        scene["materials"] = {m: {"type": KIND, **SPEC} for m in scene["materials"]}
        out.append(ConformanceCase(base.stage, base.dim, KIND, scene, dtype))
    return out


@pytest.fixture
def sixth(monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).parent))
    undo = register()
    yield
    undo()


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_the_harness_passes_on_the_numba_backend(sixth, dtype):
    report = check("numba", cases(dtype))
    assert not report.not_applicable and len(report.results) == len(BASE_CASES)
    failed = {r.case.name: (r.error, r.note) for r in report.results if not r.passed}
    assert failed == {} and all(r.errors for r in report.results)  # every case compared its outputs


SIMULATED = r'''
import json, sys
sys.path.insert(0, sys.argv[1])
import test_sixth_material as t
from mpmref.backends.capabilities import Implements
from mpmref.backends.cuda import CudaBackend
from mpmref.conformance import check
from mpmref.physics.catalogue import MATERIALS

t.register()
CudaBackend.implements = Implements(stepping=("sync",), rigid_bodies=False, materials=tuple(MATERIALS))  # + the new
report = check("cuda", t.cases("float64") + t.cases("float32"))
print("RESULT " + json.dumps({"not_applicable": len(report.not_applicable),
                              "cases": {r.case.name: [r.error, r.rtol, r.note] for r in report.results}}))
'''


def test_the_harness_passes_on_the_gpu_backend_in_the_simulator():
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1"}
    done = subprocess.run([sys.executable, "-c", SIMULATED, str(Path(__file__).parent)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=1800)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    assert done.returncode == 0 and lines, done.stderr[-3000:]
    out = json.loads(lines[-1][len("RESULT "):])
    assert out["not_applicable"] == 0 and len(out["cases"]) == 2 * len(BASE_CASES)
    assert {name: v for name, v in out["cases"].items() if not v[0] <= v[1]} == {}


def test_its_kernels_compile_for_the_h100(sixth):
    """The particle kernels of a scene of the sixth material and the fluid (two laws, the dispatch between them), and
    P2G's prelude, which computes the stress by the law, for compute capability 9.0."""
    from test_cuda_kernels import NO_COMPILER

    if NO_COMPILER:
        pytest.skip(NO_COMPILER)
    from mpmref.backends.cuda.kernels import Config, Kernels

    base = cases()[2]
    scene = json.loads(json.dumps(base.scene_dict))
    scene["materials"]["water"] = {"type": "fluid", "K": 400.0, "gamma": 7.0, "rho": 1.0}
    kernels = Kernels(Config.of(replace(base, scene_dict=scene).scene())).all()
    ptx = {name: kernels[name].ptx((9, 0)) for name in ("particles.stress", "particles.summarize", "p2g.prelude")}
    assert all(".target sm_90" in text and ".entry" in text for text in ptx.values())
