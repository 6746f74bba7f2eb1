"""No module of the package imports a module that imports it back (module-level or inside a function)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

def module_name(path):
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path, modules):
    """The package's modules that ``path`` imports: ``from . import x`` names the submodule ``x``, not the package."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    package = parts[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(list(package[:len(package) - node.level + 1] if node.level else []) +
                            ([node.module] if node.module else []))
            submodules = {f"{base}.{a.name}" for a in node.names} & modules
            found |= submodules or {base}
    return found & modules


def test_no_module_imports_one_that_imports_it_back():
    paths = sorted((ROOT / "mpmref").rglob("*.py"))
    modules = {module_name(p) for p in paths}
    edges = {module_name(p): imports_of(p, modules) - {module_name(p)} for p in paths}
    cycles = {tuple(sorted((a, b))) for a in edges for b in edges[a] if a in edges.get(b, ())}
    assert cycles == set()


def test_the_import_reader_resolves_relative_imports():
    modules = {module_name(p) for p in (ROOT / "mpmref").rglob("*.py")}
    found = imports_of(ROOT / "mpmref" / "backends" / "numba" / "backend.py", modules)
    assert {"mpmref.backends.base", "mpmref.backends.numba.cpic", "mpmref.physics.interface"} <= found
    assert "mpmref.backends.numba" not in found  # `from . import cpic` names the submodule
