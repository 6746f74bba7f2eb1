"""The Numba backend's file layout (its own folder and the pointwise physics it compiles): files of at most 400
lines, compiled kernels of at most 20 parameters, one declared interface for the transfer kernels of both
dimensions, and the CPIC fits read by name."""

import ast
import inspect
from pathlib import Path

import pytest

from mpmref.backends.numba.transfers import TRANSFER_KERNELS, DimensionTransfers

BACKENDS = Path(__file__).resolve().parent.parent / "mpmref" / "backends"
SOURCES = sorted(path for folder in ("numba", "pointwise") for path in (BACKENDS / folder).rglob("*.py"))
MAX_LINES = 400
MAX_PARAMETERS = 20


def decorator_name(node):
    """``njit`` for ``@njit``, ``@njit(...)``, ``@numba.njit(...)``; the called name of any decorator."""
    target = node.func if isinstance(node, ast.Call) else node
    return target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")


def compiled_functions(path):
    """Every function of ``path`` (nested ones too) decorated with Numba's ``jit`` or ``njit``, ``pointwise``
    (compiled with ``njit`` for the CPU) or ``parallel_kernel`` (:mod:`mpmref.backends.numba.twin`)."""
    for node in ast.walk(ast.parse(path.read_text())):
        compilers = ("jit", "njit", "pointwise", "parallel_kernel")
        if isinstance(node, ast.FunctionDef) and any(decorator_name(d) in compilers for d in node.decorator_list):
            yield node


def parameter_count(function):
    args = function.args
    return (len(args.posonlyargs) + len(args.args) + len(args.kwonlyargs) + (args.vararg is not None)
            + (args.kwarg is not None))


def test_the_walk_finds_the_compiled_kernels():
    found = {f.name for path in SOURCES for f in compiled_functions(path)}
    assert {"p2g", "g2p", "gather", "tags", "move_particle", "deform_particle", "grid_velocity",
            "project_at_wall"} <= found


def test_no_file_of_the_backend_is_longer_than_400_lines():
    lengths = {str(path.relative_to(BACKENDS)): len(path.read_text().splitlines()) for path in SOURCES}
    assert {name: n for name, n in lengths.items() if n > MAX_LINES} == {}


def test_no_compiled_kernel_takes_more_than_20_parameters():
    too_many = {f"{path.relative_to(BACKENDS)}:{f.lineno} {f.name}": parameter_count(f)
                for path in SOURCES for f in compiled_functions(path) if parameter_count(f) > MAX_PARAMETERS}
    assert too_many == {}


def test_the_cpic_fits_are_read_by_name():
    assert [path.name for path in SOURCES if "fits[" in path.read_text()] == []


# ---------------------------------------------------------------------- the transfer kernels of each dimension
CONFIGURATIONS = {"p2g_kernel": (1, 3, True, False, True, 4, False, True),  # quadratic, APIC, MLS force, fused
                  "g2p_kernel": (1, 3, True, False, True, False, 4),
                  "kick_gather_kernel": (1, 3, 4)}


def test_both_dimensions_have_the_declared_transfer_kernels():
    assert sorted(TRANSFER_KERNELS) == [2, 3]
    assert all(isinstance(k, DimensionTransfers) for k in TRANSFER_KERNELS.values())
    assert set(CONFIGURATIONS) == set(DimensionTransfers._fields)


@pytest.mark.parametrize("stage", DimensionTransfers._fields)
def test_the_kernels_of_both_dimensions_take_the_same_arguments(stage):
    """The factories, and the kernels they build (the Python functions, which nothing here compiles)."""
    factory_2d, factory_3d = (getattr(TRANSFER_KERNELS[d], stage) for d in (2, 3))
    assert inspect.signature(factory_2d) == inspect.signature(factory_3d)
    kernel_2d, kernel_3d = (f(*CONFIGURATIONS[stage]) for f in (factory_2d, factory_3d))
    assert inspect.signature(kernel_2d.py_func) == inspect.signature(kernel_3d.py_func)
    assert kernel_2d is factory_2d(*CONFIGURATIONS[stage])  # one kernel per configuration
