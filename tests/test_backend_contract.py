"""The backend contract (mpmref.backends.base): every backend of BACKENDS has every stage with the protocol's
arguments, make_backend refuses one that lacks a stage, and backends import neither the steppers built on
them nor each other."""

import ast
import inspect
from pathlib import Path

import pytest

from mpmref import Scene
from mpmref.backends import BACKENDS, checked, make_backend
from mpmref.backends.base import (
    ASYNC_BACKEND_STAGES,
    BACKEND_STAGES,
    CPIC_BACKEND_STAGES,
    FUSED_BACKEND_STAGES,
    Backend,
    CoupledBackend,
    FusedBackend,
)
from mpmref.errors import BackendError

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "mpmref"
CUT2D = ROOT / "examples" / "cut2d.toml"


def protocol_methods(protocol, own=False):
    """The method names a protocol declares (``own``: only those it adds to its bases)."""
    names = {n for n, v in vars(protocol).items() if inspect.isfunction(v) and not n.startswith("_")}
    if own:
        return names
    return names.union(*(protocol_methods(b) for b in protocol.__mro__[1:] if b.__dict__.get("_is_protocol")))


def test_the_stage_lists_are_the_protocols_methods():
    assert protocol_methods(Backend) == set(BACKEND_STAGES + ASYNC_BACKEND_STAGES) | {"running"}
    assert protocol_methods(CoupledBackend, own=True) == set(CPIC_BACKEND_STAGES)


@pytest.mark.parametrize("name", BACKENDS)
def test_every_backend_is_a_coupled_backend_with_the_protocols_arguments(name):
    backend = make_backend(name, Scene.from_toml(CUT2D))
    assert isinstance(backend, Backend) and isinstance(backend, CoupledBackend)
    for stage in protocol_methods(CoupledBackend):
        declared = list(inspect.signature(getattr(CoupledBackend, stage)).parameters)[1:]  # without self
        actual = list(inspect.signature(getattr(backend, stage)).parameters)
        assert actual[:len(declared)] == declared, f"{name}.{stage}{tuple(actual)} against the protocol's {declared}"


@pytest.mark.parametrize("name", BACKENDS)
def test_every_backend_also_folds_the_force_into_p2g_with_the_protocols_arguments(name):
    """The optional stage of :class:`FusedBackend`, which the steppers use where they can."""
    assert protocol_methods(FusedBackend, own=True) == set(FUSED_BACKEND_STAGES)
    backend = make_backend(name, Scene.from_toml(CUT2D))
    assert isinstance(backend, FusedBackend)
    for stage in FUSED_BACKEND_STAGES:
        declared = list(inspect.signature(getattr(FusedBackend, stage)).parameters)[1:]
        assert list(inspect.signature(getattr(backend, stage)).parameters)[:len(declared)] == declared


def test_make_backend_refuses_a_backend_without_a_stage_its_scene_needs():
    backend = make_backend("numpy", Scene.from_toml(CUT2D))

    class WithoutCpic:
        scene = backend.scene

    for stage in BACKEND_STAGES + ASYNC_BACKEND_STAGES + ("running",):
        setattr(WithoutCpic, stage, staticmethod(getattr(backend, stage)))
    with pytest.raises(BackendError, match=r"lacks the stage cpic_contact\(particles, prepared, rigid, dt\)") as error:
        checked(WithoutCpic(), "partial")
    assert "running" not in str(error.value)  # the stages it has are not named


def imported_modules(path):
    """Absolute names of the modules ``path`` imports (relative imports resolved; function-level ones too)."""
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package.split(".")[:len(package.split(".")) - node.level + 1] if node.level else []
            names.add(".".join(base + ([node.module] if node.module else [])))
    return names


@pytest.mark.parametrize("path", sorted((PACKAGE / "backends").rglob("*.py")), ids=lambda p: p.name)
def test_backends_import_neither_the_steppers_nor_each_other(path):
    imports = imported_modules(path)
    assert not {m for m in imports if m.startswith("mpmref.steppers")}, f"{path}: imports the steppers"
    own = path.relative_to(PACKAGE / "backends").parts[0]
    if own == "__init__.py":
        return  # the registry: make_backend imports each backend
    others = {f"mpmref.backends.{b}" for b in BACKENDS} - {f"mpmref.backends.{own}"}
    assert not {m for m in imports if any(m == o or m.startswith(o + ".") for o in others)}, \
        f"{path}: imports another backend"


def test_the_import_resolver_sees_relative_and_function_level_imports():
    module = PACKAGE / "backends" / "numba" / "backend.py"
    imports = imported_modules(module)
    assert {"mpmref.physics.interface", "mpmref.backends.base", "mpmref.backends.numba"} <= imports
