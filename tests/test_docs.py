"""The documentation in docs/ stays true: its Python examples run, its links resolve, its references are complete.

* Every ```python block of every docs/*.md page is executed (one test per block, id ``page.md:index``), in a
  fresh namespace, from the repository root, so that relative paths such as ``examples/mpm88.toml`` work.
  Blocks meant only for display use ```text, ```bash or ```toml; ```toml blocks must at least be valid TOML.
* Every relative link target exists; ``#anchors`` into docs pages name real headings; a link whose text is a
  qualified name (```mpmref.x.y```) points at the source file that defines that object.
* The scene reference lists every key and option the validator accepts, and the pages list every
  diagnostics column and command-line option.
"""

import ast
import contextlib
import inspect
import io
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.glob("*.md"))

FENCE = re.compile(r"^```([\w+-]*)[^\n]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)
LINK = re.compile(r"\[([^\]]*)\]\(([^)\s]+)\)")
QUALNAME = re.compile(r"^`(mpmref(?:\.\w+)+)`$")


def fenced_blocks(text, language):
    return [m.group(2) for m in FENCE.finditer(text) if m.group(1) == language]


def strip_fences(text):
    return FENCE.sub("", text)


def python_blocks():
    params = []
    for page in PAGES:
        for index, code in enumerate(fenced_blocks(page.read_text(encoding="utf-8"), "python")):
            params.append(pytest.param(page, code, id=f"{page.name}:{index}"))
    return params


def watched_files():
    """Files a snippet could plausibly leave behind in the repository by mistake."""
    return {p for folder in ("docs", "reports") for p in (ROOT / folder).rglob("*") if p.is_file()}


@pytest.mark.parametrize("page, code", python_blocks())
def test_python_block_runs(page, code, monkeypatch):
    monkeypatch.chdir(ROOT)
    before = watched_files()
    namespace = {"__name__": "__docs__"}
    exec(compile(code, f"{page.relative_to(ROOT)} (python block)", "exec"), namespace)
    assert watched_files() == before, "a docs example wrote files into the repository; use a TemporaryDirectory"


def test_there_are_examples_and_none_escape_the_runner():
    """At least one block per page, and no Python block hidden under another fence tag that the runner skips."""
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        tags = {m.group(1) for m in FENCE.finditer(text)}
        assert not tags & {"py", "python3", "pycon", "ipython"}, f"{page.name}: use ```python (tested) or ```text"
        assert fenced_blocks(text, "python"), f"{page.name} has no runnable ```python example"


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_toml_blocks_are_valid_toml(page):
    """Every ```toml block parses; those that are whole scenes (dim, grid, materials, bodies) also validate."""
    from mpmref import Scene

    for code in fenced_blocks(page.read_text(encoding="utf-8"), "toml"):
        data = tomllib.loads(code)
        assert isinstance(data, dict)
        if {"dim", "grid", "materials", "bodies"} <= set(data):
            assert Scene.from_dict(data).dim == data["dim"]


# ----------------------------------------------------------------------------------------------- links
def slugs(page):
    """GitHub-style anchors of the headings of a Markdown page."""
    seen, out = {}, set()
    for line in strip_fences(page.read_text(encoding="utf-8")).splitlines():
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def links(page):
    return LINK.findall(strip_fences(page.read_text(encoding="utf-8")))


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_relative_links_resolve(page):
    problems = []
    for _, target in links(page):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        path_part, _, anchor = target.partition("#")
        path = (page.parent / path_part).resolve() if path_part else page
        if not path.exists():
            problems.append(f"{target}: {path} does not exist")
        elif anchor and path.suffix == ".md" and anchor not in slugs(path):
            problems.append(f"{target}: no heading '#{anchor}' in {path.name}")
    assert not problems, f"{page.name}:\n" + "\n".join(problems)


def resolve(qualname):
    """Import the longest importable module prefix of ``qualname`` and walk the remaining attributes."""
    import importlib

    parts = qualname.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(qualname)


#: the numbered equations of G2P, per page: each links to the short function of the NumPy reference that implements it
#: (they all linked to the one long ``g2p``)
G2P_EQUATIONS = {"mpm_cycle.md": ("eq-g2p-affine", "eq-velocity-gradient", "eq-flip-blend", "eq-deformation-update",
                                  "eq-advection", "eq-polypic-projection"),
                 "transfers.md": ("eq-pic", "eq-flip", "eq-apic", "eq-polypic"),
                 "mls_vs_classic.md": ("eq-gradient-weight-form", "eq-mls-deformation-update")}
#: the most lines of code (the docstring left out) a function that implements one equation may have
SHORT = 12


def code_links_after(page, label):
    """The qualified names of the ``Code:`` paragraph that follows the numbered equation ``label`` of ``page``."""
    paragraph = (DOCS / page).read_text(encoding="utf-8").split(f"$$ ({label})", 1)[1].strip().split("\n\n", 1)[0]
    assert paragraph.startswith("Code:"), f"{page} ({label}): no Code: paragraph after the equation"
    return re.findall(r"\[`(mpmref(?:\.\w+)+)`\]", paragraph)


def code_lines(function):
    """Lines of ``function``'s body after its docstring."""
    body = ast.parse(inspect.getsource(function)).body[0].body
    statements = body[1:] if isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) else body
    return statements[-1].end_lineno - statements[0].lineno + 1


@pytest.mark.parametrize("page, label", [(p, eq) for p, labels in G2P_EQUATIONS.items() for eq in labels])
def test_each_g2p_equation_links_to_a_short_function_that_implements_it(page, label):
    names = [n for n in code_links_after(page, label) if n.startswith("mpmref.backends.numpy.transfers.")
             and not n.endswith(".p2g")]      # P2G's half of a transfer's equation
    assert names and "mpmref.backends.numpy.transfers.g2p" not in names, names
    for name in names:
        assert code_lines(resolve(name)) <= SHORT, f"{name} has {code_lines(resolve(name))} lines of code"


def lacks_optional_dependency(module):
    """``module`` exists but imports a package that is not installed (e.g. taichi, the optional ``bench``
    extra)."""
    import importlib

    try:
        importlib.import_module(module)
    except ModuleNotFoundError as exc:
        return bool(exc.name) and not module.startswith(exc.name)
    return False


def defined_at_top_level(path, qualname):
    """``qualname``'s object is a top-level class/def (or a method of one) in the source file ``path``."""
    import ast

    names = qualname.split(".")
    tree = ast.parse(Path(path).read_text())
    nodes = {n.name: n for n in tree.body if isinstance(n, (ast.ClassDef, ast.FunctionDef))}
    return any(name in nodes for name in names)


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_code_links_name_objects_defined_in_the_linked_file(page):
    checked = 0
    for text, target in links(page):
        m = QUALNAME.match(text)
        if not m or not target.endswith(".py"):
            continue
        path = (page.parent / target).resolve()
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        if m.group(1).startswith(module + ".") and lacks_optional_dependency(module):
            # checked from the source text, without importing the optional package
            rest = m.group(1)[len(module) + 1:]
            assert defined_at_top_level(path, rest), f"{m.group(1)} not in {target}"
            checked += 1
            continue
        obj = resolve(m.group(1))
        source = Path(inspect.getsourcefile(inspect.unwrap(obj))).resolve()
        assert source == (page.parent / target).resolve(), f"{m.group(1)} is defined in {source}, link says {target}"
        checked += 1
    if page.name == "mpm_cycle.md":
        assert checked >= 20  # every equation there links to its implementation


# ---------------------------------------------------------------------------------- reference coverage
def minimal_scene():
    return {
        "dim": 2,
        "grid": {"size": 1.0, "cells": 16},
        "method": {},
        "materials": {"m": {"type": "fixed_corotated", "E": 1.0e3}},
        "bodies": [{"shape": "box", "material": "m", "lower": [0.3, 0.3], "upper": [0.6, 0.6]}],
        "boundary": {"walls": {}},
        "time": {"dt": 1.0e-3},
        "output": {},
    }


def accepted_keys(mutate):
    """The keys the validator accepts at one place, read from its own 'unknown key' error."""
    from mpmref import Scene, SceneError

    data = minimal_scene()
    mutate(data)
    with pytest.raises(SceneError) as info:
        Scene.from_dict(data)
    allowed = info.value.allowed
    assert "known keys" in allowed, allowed
    return set(ast.literal_eval(allowed[allowed.index("["):]))


def probe(*path, material_type=None):
    """A mutation that puts an unknown key at ``path`` (optionally after switching the material's type)."""
    def mutate(data):
        if material_type is not None:
            required = {"K": 1.0e3} if material_type == "fluid" else {"E": 1.0e3}
            data["materials"]["m"] = {"type": material_type, **required}
        target = data
        for key in path:
            target = target[key]
        target["__probe__"] = 1

    return mutate


def test_scene_reference_lists_every_key_and_option():
    from mpmref import scene as sc
    from mpmref.physics.kernels import KERNELS

    text = (DOCS / "scenes.md").read_text(encoding="utf-8")
    keys = set()
    keys |= accepted_keys(probe())
    for section in ("grid", "method", "boundary", "time", "output"):
        keys |= accepted_keys(probe(section))
    keys |= accepted_keys(probe("boundary", "walls"))
    keys |= accepted_keys(probe("bodies", 0))
    if "colliders" in sc.TOP_KEYS:
        def collider_probe(data):
            data["colliders"] = [{"shape": "plane", "point": [0.0, 0.1], "normal": [0.0, 1.0], "__probe__": 1}]
        keys |= accepted_keys(collider_probe)
    for kind in sc.MATERIAL_TYPES:
        keys |= accepted_keys(probe("materials", "m", material_type=kind))
    missing = sorted(k for k in keys if f"`{k}`" not in text)
    assert not missing, f"docs/scenes.md does not document the scene keys {missing}"

    options = set(sc.SCHEMES) | set(sc.FORCES) | set(KERNELS) | set(sc.WALL_TYPES) | set(sc.DOMAIN_EXIT_POLICIES)
    options |= set(sc.DTYPES) | set(sc.SHAPES) | set(sc.SAMPLINGS) | set(sc.OUTPUT_FIELDS) | set(sc.MATERIAL_TYPES)
    options |= set(getattr(sc, "COLLIDER_SHAPES", ()))
    missing = sorted(o for o in options if f'"{o}"' not in text)
    assert not missing, f"docs/scenes.md does not list the allowed values {missing}"


def test_diagnostics_columns_and_cli_options_are_documented():
    from mpmref import SceneBuilder, Simulation
    from mpmref.cli import main

    started = (DOCS / "getting_started.md").read_text(encoding="utf-8")
    cycle = (DOCS / "mpm_cycle.md").read_text(encoding="utf-8")
    for dim in (2, 3):
        scene = (SceneBuilder(dim=dim).grid(size=1.0, cells=8).material("w", "fluid", K=1.0)
                 .box("w", lower=[0.4] * dim, upper=[0.6] * dim).time(dt=1e-3).build())
        for key in Simulation(scene).diagnostics():
            assert key in started, f"diagnostics column '{key}' missing from getting_started.md"
            if key not in ("step", "time", "deleted"):
                assert f"`{key}`" in cycle or f"`{key.rsplit('_', 1)[0]}_x`" in cycle, \
                    f"diagnostics column '{key}' is not defined in mpm_cycle.md"

    help_text = io.StringIO()
    with contextlib.redirect_stdout(help_text), pytest.raises(SystemExit):
        main(["run", "--help"])
    for option in set(re.findall(r"--[a-z][a-z-]*", help_text.getvalue())) - {"--help"}:
        assert f"`{option}" in started, f"command-line option {option} missing from getting_started.md"


# --------------------------------------------------------------------------- the site build's progress lines
def docs_build_module():
    """docs/build.py as a module (it is a script, not a package's)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_build", DOCS / "build.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


#: Sphinx's status output as a terminal gets it: a counted phase rewrites its line (``\r``), a pipe gets lines
SPHINX_STATUS = ("Running Sphinx v9.0.4\n[autosummary] generating autosummary for: "
                 + ", ".join(f"page{i}.md" for i in range(50)) + "\n"
                 "[autosummary] generating autosummary for: docs/api/mpmref.rst\n"
                 "mpmref figures: running the momentum case (quick preset)\n"
                 "mpmref figures: running the energy case (quick preset)\n"
                 + "".join(f"reading sources... [{p:3d}%] page{p}\r" for p in range(0, 101, 5))
                 + "\nWriting evaluated template result to _static/basic.css\n"
                 "Writing evaluated template result to _static/alabaster.css\n"
                 + "".join(f"writing output... [{p:3d}%] page{p}\n" for p in range(0, 101, 10))
                 + "build succeeded.\n")


def test_the_site_build_shows_a_line_per_phase_quarter_and_figure_with_its_time():
    build = docs_build_module()
    clock = iter(range(0, 1000, 10))
    out = io.StringIO()
    progress = build.Progress(out, clock=lambda: next(clock))
    for start in range(0, len(SPHINX_STATUS), 7):   # in pieces that cut lines, as a stream is written
        progress.write(SPHINX_STATUS[start:start + 7])
    shown = [line.split(" s  ", 1)[1] for line in out.getvalue().splitlines()]
    long_line = "[autosummary] generating autosummary for: " + ", ".join(f"page{i}.md" for i in range(50))
    assert shown == ["Running Sphinx v9.0.4", long_line[:build.WIDTH - 1] + "…",
                     "mpmref figures: running the momentum case (quick preset)",
                     "mpmref figures: running the energy case (quick preset)",
                     "reading sources... [  0%] page0", "reading sources... [ 25%] page25",
                     "reading sources... [ 50%] page50", "reading sources... [ 75%] page75",
                     "Writing evaluated template result to _static/basic.css",
                     "writing output... [  0%] page0", "writing output... [ 30%] page30",
                     "writing output... [ 50%] page50", "writing output... [ 80%] page80", "build succeeded."]
    assert out.getvalue().splitlines()[0] == "docs    10 s  Running Sphinx v9.0.4"   # seconds since the start
