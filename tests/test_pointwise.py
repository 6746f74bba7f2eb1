"""The pointwise physics of the compiled backends (mpmref.backends.pointwise): each material's declared law gives the
reference's stress, return map and wave speed; the device version of a function is the same source, calling the
device versions of what it calls; and a float32 run computes in float32 (no float64 arithmetic where the law does not
ask for it)."""

import re

import numpy as np
import pytest
from numba import njit

from mpmref.backends.pointwise import is_pointwise, on_device, stencil, svd
from mpmref.backends.pointwise import laws as pointwise_laws
from mpmref.backends.pointwise.grid import project_at_wall
from mpmref.backends.pointwise.laws import WORK, functions, parameter_table
from mpmref.physics.catalogue import MATERIALS
from mpmref.physics.materials import CompiledLaw, kirchhoff_stress_of, wave_speed_of
from mpmref.state import Particles

REQUIRED = {"E": 2.0e3, "K": 4.0e2}
#: the harness's bound in float64 (docs/conformance.md)
RTOL = 1e-12


def example(cls):
    """A material of class ``cls`` with its required parameters set (and a cohesion, so that sand's apex is off 0)."""
    fields = {f: v for f, v in REQUIRED.items() if f in cls.__dataclass_fields__}
    if "cohesion" in cls.__dataclass_fields__:
        fields["cohesion"] = 0.01
    return cls(**fields)


def states(dim, rng, n=40):
    """Deformation gradients near rotations, stretched by up to 10 % (some beyond snow's clamp and sand's cone), with
    J = det F and a plastic ratio around 1."""
    F = np.empty((n, dim, dim))
    for p in range(n):
        Q, _ = np.linalg.qr(rng.standard_normal((dim, dim)))
        Q[:, 0] *= np.sign(np.linalg.det(Q))  # a rotation
        F[p] = Q @ (np.eye(dim) + 0.1 * rng.uniform(-1, 1, (dim, dim)))
    return F, np.linalg.det(F), rng.uniform(0.8, 1.2, n)


def relative(got, expected):
    return float(np.abs(got - expected).max() / max(np.abs(expected).max(), 1e-300))


@pytest.mark.parametrize("kind", MATERIALS)
def test_every_material_declares_a_law_whose_functions_exist(kind):
    cls = MATERIALS[kind]
    law = cls.compiled
    assert isinstance(law, CompiledLaw)
    found = functions(law)
    assert is_pointwise(found.stress) and is_pointwise(found.wave_speed)
    assert (found.return_map is not None) == cls.plastic  # a return map exactly where the material is plastic
    material = example(cls)
    assert all(np.isfinite(getattr(material, name)) for name in law.parameters)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kind", MATERIALS)
def test_each_law_gives_the_reference_stress_return_map_and_wave_speed(kind, dim, rng):
    """The law's pointwise functions, compiled for the CPU, on each particle, against the reference class's own NumPy
    methods on the batch (LAPACK's SVD there, the pointwise Jacobi or closed form here): within the harness's bound.
    A parameter row read in another order than the declaration's would fail it (μ and λ, K and γ differ)."""
    material = example(MATERIALS[kind])
    found = functions(type(material).compiled)
    prm = parameter_table([material])[0]
    F, J, Jp = states(dim, rng)
    particles = Particles(x=np.zeros((len(J), dim)), v=np.zeros((len(J), dim)), mass=np.ones(len(J)),
                          vol0=np.ones(len(J)), material=np.zeros(len(J), dtype=np.int32), F=F, J=J, Jp=Jp)
    every = np.arange(len(J))
    tau, work = np.empty((len(J), dim, dim)), np.empty((WORK, dim, dim))
    for p in every:
        found.stress(prm, F[p], J[p], Jp[p], tau[p], work)
    assert relative(tau, kirchhoff_stress_of(material, particles, every)) <= RTOL
    speeds = np.array([found.wave_speed(prm, F[p], J[p], Jp[p]) for p in every])
    assert relative(speeds, wave_speed_of(material, particles, every)) <= RTOL
    if found.return_map is not None:
        F_new, Jp_new = F.copy(), Jp.copy()
        for p in every:
            Jp_new[p] = found.return_map(prm, F_new[p], Jp[p], work)
        F_ref, Jp_ref = material.return_map(F, Jp)
        assert not np.array_equal(F_ref, F)  # the states reach the yield surface: the projection is checked
        assert relative(F_new, F_ref) <= RTOL and relative(Jp_new, Jp_ref) <= RTOL


def python_device(function):
    """What numba-cuda's simulator makes of a device function: the Python function itself."""
    return function


@pytest.mark.parametrize("dim", [2, 3])
def test_a_device_version_is_the_same_source_calling_device_versions(dim, rng):
    """The device version of a law (here with the simulator's decorator, which runs the Python source) reads the
    device versions of what it calls, and computes what the CPU's compiled version computes, to the harness's bound
    (the libraries' ``atan2``, ``hypot`` or ``log`` may round their last bit apart)."""
    law = pointwise_laws.snow_stress
    on_gpu = on_device(law, python_device)
    assert on_gpu.__code__ is law.py_func.__code__
    assert on_gpu.__globals__["corotated_into"] is on_device(pointwise_laws.corotated_into, python_device)
    assert on_device(pointwise_laws.corotated_into, python_device).__globals__["polar_rotation"] is on_device(
        svd.polar_rotation, python_device)
    material = example(MATERIALS["snow"])
    prm = parameter_table([material])[0]
    F, J, Jp = states(dim, rng, n=10)
    for p in range(len(J)):
        cpu, gpu = np.empty((dim, dim)), np.empty((dim, dim))
        law(prm, F[p], J[p], Jp[p], cpu, np.empty((WORK, dim, dim)))
        on_gpu(prm, F[p], J[p], Jp[p], gpu, np.empty((WORK, dim, dim)))
        assert relative(gpu, cpu) <= RTOL


#: LLVM instructions of float64 arithmetic
DOUBLE_ARITHMETIC = re.compile(r"= (fadd|fsub|fmul|fdiv|fneg|fcmp \w+) (fast |contract )*double|@llvm\.\w+\.f64")


def float32_code(function, *args):
    """The LLVM IR of ``function`` compiled afresh (Numba shows no IR of what it loads from its disk cache) for
    ``args``, a float32 call: its own code and that of the functions it inlines, not that of those it calls."""
    fresh = njit(function.py_func)
    fresh(*args)
    code = fresh.inspect_llvm(fresh.signatures[0])
    assert "define" in code, function
    return code


def test_a_float32_law_computes_in_float32_on_the_cpu():
    """Laws, decompositions, weights, PolyPIC's basis and walls of a float32 run: their compiled code does no float64
    arithmetic (a float literal would promote it); the parameter rows are float64 and converted once. The wave speeds
    compute in float64 by design and are left out. Each function that another calls without inlining it is checked
    by itself."""
    f32 = np.float32
    F = (np.eye(3) + 0.05).astype(f32)
    work, tau, square = np.empty((WORK, 3, 3), f32), np.empty((3, 3), f32), np.empty((3, 3), f32)
    snow = parameter_table([example(MATERIALS["snow"])])[0]
    sand = parameter_table([example(MATERIALS["sand"])])[0]
    calls = {"snow stress": (pointwise_laws.snow_stress, snow, F, f32(1.0), f32(1.0), tau, work),
             "snow return map": (pointwise_laws.snow_return_map, snow, F.copy(), f32(1.0), work),
             "sand stress": (pointwise_laws.sand_stress, sand, F, f32(1.0), f32(1.0), tau, work),
             "sand return map": (pointwise_laws.sand_return_map, sand, F.copy(), f32(1.0), work),
             "neo-Hookean stress": (pointwise_laws.neo_hookean_stress, sand, F, f32(1.0), f32(1.0), tau, work),
             "fluid stress": (pointwise_laws.fluid_stress, np.array([4e2, 7.0, 1.0]), F, f32(0.9), f32(1.0), tau,
                              work),
             "3D SVD": (svd.svd_3d, F, tau, np.empty(3, f32), square),
             "2D SVD": (svd.svd_2d, F[:2, :2].copy(), tau[:2, :2].copy(), np.empty(2, f32), square[:2, :2].copy()),
             "quadratic stencil": (stencil.quadratic, f32, f32(0.75)),
             "cubic stencil": (stencil.cubic, f32, f32(1.25)),
             "PolyPIC basis": (stencil.axis_basis, np.full(3, 0.3, f32), f32(0.75), f32(0.1), square, np.empty(3, f32)),
             "walls": (project_at_wall, np.ones((1, 3), f32), 0, 0, f32(1.0), 3, f32(0.3))}
    doubled = {name: DOUBLE_ARITHMETIC.findall(float32_code(*call)) for name, call in calls.items()}
    assert {name: found for name, found in doubled.items() if found} == {}
