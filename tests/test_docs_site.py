"""The documentation site: its table of contents, its equation links, and the build itself.

* Every page is in the site's table of contents.
* Every numbered equation (MyST's ``$$ ... $$ (eq-label)``) is followed by a paragraph with ``Code:`` and
  a link to each object that implements it (link text: the qualified name); each such object's docstring
  links back (a paragraph ``Docs: docs/PAGE.md#section, ...``) to the section that holds the equation, and every such
  back-link in the sources names a section whose equations name that object. So a function that moves,
  is renamed or disappears, or a section that is renamed, fails here (the linked file is checked by
  ``test_docs.py``).

The fast checks need no Sphinx. The full build (``docs/build.py``: Sphinx, MyST-Parser, autodoc, viewcode,
warnings as errors, every code link landing on its object's line) runs when the ``docs`` extra is
installed (``pip install -e '.[docs]'``) and is skipped otherwise; run it with
``.venv/bin/python -m pytest tests/test_docs_site.py``.
"""

import ast
import importlib
import importlib.util
import inspect
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from test_docs import resolve, slugs

PAGES = sorted(Path(__file__).resolve().parent.parent.glob("docs/*.md"))
EQUATION = re.compile(r"^\$\$[ \t]*\n((?:(?!\$\$).)*?)^\$\$[ \t]*\((eq-[a-z0-9-]+)\)[ \t]*$", re.MULTILINE | re.DOTALL)
HEADING = re.compile(r"^#{1,6}[ \t]+(.*?)[ \t]*#*[ \t]*$", re.MULTILINE)
CODE_LINK = re.compile(r"\[`((?:mpmref|verification|exercises)(?:\.\w+)+)`\]\([^)]+\.py\)")
BACKLINK = re.compile(r"docs/(\w+\.md)#([\w-]+)")
SOURCES = sorted(p for folder in ("mpmref", "verification")
                 for p in (Path(__file__).resolve().parent.parent / folder).rglob("*.py"))

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
HAS_SPHINX = all(importlib.util.find_spec(m) is not None for m in ("sphinx", "myst_parser"))


def toctree_entries():
    text = (DOCS / "index.md").read_text(encoding="utf-8")
    block = re.search(r"^```\{toctree\}\n(.*?)^```", text, re.MULTILINE | re.DOTALL)
    assert block, "docs/index.md has no {toctree} block"
    return [line.strip() for line in block.group(1).splitlines() if line.strip() and not line.startswith(":")]


def test_readme_lists_every_example_with_a_line_on_what_it_shows():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    for example in sorted((ROOT / "examples").glob("*.toml")):
        line = next((ln for ln in readme.splitlines() if f"`{example.name}`" in ln and ln.startswith("- ")), None)
        assert line is not None, f"README.md does not list examples/{example.name}"
        assert len(line.split(":", 1)[-1].split()) >= 4, f"README.md's line for {example.name} says too little"


TRACKER_REFERENCE = re.compile(r"\bissues?\s+#?\d+|\.\./shared|DESIGN\.md|(?<![\w&/:])#\d+\b", re.IGNORECASE)


def test_no_references_to_tracker_issues_or_files_outside_the_repository():
    """Readers see the repository only: no "issue 12", "#12", "../shared" or design files it does not hold."""
    files = [ROOT / "README.md", *(p for folder in ("docs", "mpmref", "verification", "tests", "examples")
                                   for p in (ROOT / folder).rglob("*") if p.suffix in (".md", ".py", ".toml"))]
    hits = [f"{path.relative_to(ROOT)}:{n}: {line.strip()}" for path in files if "_build" not in path.parts
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            if TRACKER_REFERENCE.search(line) and path.name != "test_docs_site.py"]
    assert not hits, "\n".join(hits)


def test_every_page_is_in_the_table_of_contents_once():
    entries = toctree_entries()
    pages = sorted(p.stem for p in DOCS.glob("*.md") if p.stem != "index")
    assert sorted(entries) == pages, "docs/index.md's toctree must list every page of docs/ exactly once"


@pytest.mark.skipif(not HAS_SPHINX, reason="the docs extra is not installed: pip install -e '.[docs]'")
def test_the_build_resolves_code_links_to_definitions_and_refuses_missing_ones():
    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        from mpmref_links import anchor_in
    finally:
        sys.path.remove(str(DOCS / "_ext"))
    kernels = ROOT / "mpmref" / "physics" / "kernels.py"
    report = ROOT / "mpmref" / "conformance" / "report.py"
    assert anchor_in("mpmref.physics.kernels.Stencil.node_weight", "mpmref.physics.kernels", kernels) == \
        "Stencil.node_weight"
    assert anchor_in("mpmref.conformance.check", "mpmref.conformance.report", report) == "check"  # re-export
    assert anchor_in("mpmref.physics.kernels", "mpmref.physics.kernels", kernels) == ""
    assert anchor_in("mpmref.physics.kernels.no_such_function", "mpmref.physics.kernels", kernels) is None
    assert anchor_in("mpmref.physics.kernels.compute_stencil", "mpmref.physics.materials",
                     ROOT / "mpmref" / "physics" / "materials.py") is None


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built once by ``docs/build.py`` (warnings as errors) for every test of the build below."""
    if not HAS_SPHINX:
        pytest.skip("the docs extra is not installed: pip install -e '.[docs]'")
    out = tmp_path_factory.mktemp("site") / "html"
    run = subprocess.run([sys.executable, str(DOCS / "build.py"), "--no-open", "--out", str(out)],
                         capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 0, run.stdout + run.stderr
    return out


def test_site_builds_with_warnings_as_errors(site):
    # one equation's implementation link lands on the function's line in the rendered source
    cycle = (site / "mls_vs_classic.html").read_text(encoding="utf-8")
    assert 'href="./_modules/mpmref/backends/numpy/transfers.html#mls_gradient_weight"' in cycle
    source = (site / "_modules" / "mpmref" / "backends" / "numpy" / "transfers.html").read_text(encoding="utf-8")
    assert 'id="mls_gradient_weight"' in source
    # and back: the function's docstring links to the section that derives it, in one click
    assert '<a href="../../../../mls_vs_classic.html#two-gradient-weights">' in source


# ------------------------------------------------------------------------------------ the site offline
#: a URL that leaves the machine: http(s) or protocol-relative (``//host/...``, which a page served by http(s) follows)
REMOTE = r"""(?:https?:)?//[^\s"'<>)\\]+"""
#: in HTML, or in markup that a script writes: a tag whose source loads when the page is shown
REMOTE_TAG = re.compile(r"<(script|link|img|iframe|source|embed|object|audio|video|track)\b[^>]*?"
                        r"\b(?:src|href|data|srcset|poster)\s*=\s*\\?[\"']?(" + REMOTE + ")", re.IGNORECASE)
#: in CSS (a file, a <style> block or a string in a script): an imported sheet or a fetched font or image
REMOTE_CSS = re.compile(r"(@import|url\()\s*(?:url\()?\s*\\?[\"']?(" + REMOTE + ")", re.IGNORECASE)


def remote_sources(text):
    """``[(what, url)]`` for each thing in ``text`` (HTML, CSS or JavaScript) that a browser would fetch remotely.

    A remote source is a ``script``/``link``/``img``/``iframe``/... tag whose ``src``/``href``/... is an
    http(s) or protocol-relative URL, or a CSS ``@import``/``url(...)`` of one. URLs that are names and not
    loads (an XML namespace such as ``http://www.w3.org/2000/svg``, an ``<a href>`` the reader may follow)
    are not sources.
    """
    return [(m.group(1).lower(), m.group(2)) for pattern in (REMOTE_TAG, REMOTE_CSS) for m in pattern.finditer(text)]


def test_the_remote_source_scan_finds_what_loads_and_only_that():
    assert remote_sources('<script defer src="https://cdn.example.org/mathjax/tex.js"></script>') == \
        [("script", "https://cdn.example.org/mathjax/tex.js")]
    assert remote_sources("<link rel='stylesheet' href='//fonts.example.org/a.css'>") == \
        [("link", "//fonts.example.org/a.css")]
    assert remote_sources('s.innerHTML = "<img src=\\"http://example.org/x.png\\">"') == \
        [("img", "http://example.org/x.png")]
    assert remote_sources('@import url("https://fonts.example.org/css?family=A");') == \
        [("@import", "https://fonts.example.org/css?family=A")]
    assert remote_sources("src: url(https://example.org/font.woff) format('woff');") == \
        [("url(", "https://example.org/font.woff")]
    assert remote_sources('<a href="https://www.mathjax.org">MathJax</a>') == []
    assert remote_sources('e.createElementNS("http://www.w3.org/2000/svg", "rect")') == []
    assert remote_sources('<script src="_static/mathjax/tex-chtml.js"></script><img src="../x.png">') == []


def test_no_built_page_loads_anything_remote(site):
    """Every built HTML, CSS and JavaScript file: no remote source (MathJax comes with the site, _static/mathjax)."""
    files = [p for p in site.rglob("*") if p.suffix in (".html", ".css", ".js")]
    assert len(files) > 100 and (site / "_static" / "mathjax" / "tex-chtml.js").exists()
    hits = [f"{path.relative_to(site)}: {what} {url}" for path in files
            for what, url in remote_sources(path.read_text(encoding="utf-8", errors="replace"))]
    assert not hits, "\n".join(hits[:20])


def chromium():
    """Debian's chromium (.ci/run installs it); a skip where it is missing, a failure in CI."""
    path = shutil.which("chromium")
    if path is None:
        if os.environ.get("CI"):
            pytest.fail("CI has no chromium: .ci/run installs it (apt-get install chromium)")
        pytest.skip("no headless browser to open the site: apt-get install chromium (Debian's package)")
    return path


def open_offline(page, profile, netlog):
    """The DOM of ``page`` after its scripts ran in headless chromium, with every host name unresolvable."""
    run = subprocess.run([chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                          "--disable-component-update", "--disable-sync", "--no-first-run",
                          f"--user-data-dir={profile}", "--host-resolver-rules=MAP * ~NOTFOUND",
                          f"--log-net-log={netlog}", "--virtual-time-budget=20000", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr[-2000:]
    return run.stdout


def requests_by_pages(netlog):
    """The URLs that a page asked the network for (the browser's own requests have no origin)."""
    events = json.loads(netlog.read_text(encoding="utf-8"))["events"]
    return sorted({e["params"]["url"] for e in events
                   if "initiator" in e.get("params", {}) and e["params"]["initiator"] != "not an origin"})


def test_an_equation_is_typeset_in_a_headless_browser_without_network(site, tmp_path):
    """The MPM cycle chapter (inline, display and amsmath equations) opened in chromium with no network:
    MathJax typesets every equation (one ``mjx-container`` per math element, no TeX error, no raw ``\\[``
    or ``\\(`` left) and the page asks the network for nothing."""
    page = site / "mpm_cycle.html"
    maths = len(re.findall(r'class="math notranslate nohighlight"', page.read_text(encoding="utf-8")))
    assert maths > 100
    dom = open_offline(page, tmp_path / "profile", tmp_path / "netlog.json")
    assert dom.count("<mjx-container") == maths, "not every equation was typeset"
    assert "<mjx-merror" not in dom, "MathJax reported a TeX error"
    assert "\\[" not in dom and "\\(" not in dom, "raw TeX source left on the page"
    assert requests_by_pages(tmp_path / "netlog.json") == []


# ------------------------------------------------------------------------------------ equation links
def github_slug(title, seen):
    slug = re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")
    n = seen.get(slug, 0)
    seen[slug] = n + 1
    return slug if n == 0 else f"{slug}-{n}"


def numbered_equations(page):
    """``[(label, section slug, [qualified names after "Code:"])]`` for each numbered equation of ``page``."""
    text = page.read_text(encoding="utf-8")
    headings, seen = [], {}
    fences = [(m.start(), m.end()) for m in re.finditer(r"^```.*?^```", text, re.MULTILINE | re.DOTALL)]
    for m in HEADING.finditer(text):
        if not any(a <= m.start() < b for a, b in fences):
            headings.append((m.start(), github_slug(m.group(1), seen)))
    out = []
    for m in EQUATION.finditer(text):
        section = [slug for start, slug in headings if start < m.start()][-1]
        after = text[m.end():].lstrip("\n").split("\n\n", 1)[0]
        code = after.split("Code:", 1)[1] if "Code:" in after else ""
        names = CODE_LINK.findall(code)
        out.append((m.group(2), section, names))
    return out


def equation_index():
    return {page.name: numbered_equations(page) for page in PAGES}


def test_numbered_equations_exist_where_the_mls_chapter_needs_them():
    index = equation_index()
    for name in ("mls_vs_classic.md", "transfers.md", "mpm_cycle.md"):
        assert len(index[name]) >= 5, f"{name} has too few numbered equations"
    labels = [label for eqs in index.values() for label, _, _ in eqs]
    assert len(labels) == len(set(labels)), "equation labels must be unique across the site"


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_every_numbered_equation_links_to_code_that_links_back(page):
    problems = []
    for label, section, names in numbered_equations(page):
        if not names:
            problems.append(f"({label}): no 'Code:' link in the paragraph after the equation")
        for qualname in names:
            if (page.name, section) not in backlinks_of(resolve(qualname).__doc__):
                problems.append(f"({label}): the docstring of {qualname} lacks 'Docs: docs/{page.name}#{section}'")
    assert not problems, f"{page.name}:\n" + "\n".join(problems)


def backlinks_of(doc):
    """The ``(page, slug)`` pairs of the paragraph that starts with ``Docs:`` in a docstring."""
    paragraphs = inspect.cleandoc(doc or "").split("\n\n")
    return {pair for par in paragraphs if par.startswith("Docs:") for pair in BACKLINK.findall(par)}


def docstring_backlinks():
    """``[(object, page, slug, where)]`` for every ``Docs: docs/PAGE.md#slug`` in a docstring."""
    out = []
    for path in SOURCES:
        module_name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        tree = ast.parse(path.read_text(encoding="utf-8"))
        stack = [(tree, [])]
        while stack:
            node, names = stack.pop()
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)):
                    stack.append((child, names + [child.name]))
            if not isinstance(node, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)):
                continue
            for page, slug in sorted(backlinks_of(ast.get_docstring(node, clean=False))):
                where = f"{path.relative_to(ROOT)}:{'.'.join(names) or '<module>'}"
                out.append((module_name, names, page, slug, where))
    return out


def test_every_docstring_backlink_names_a_section_whose_equations_name_the_object():
    index = equation_index()
    backlinks = docstring_backlinks()
    assert len(backlinks) >= 10
    problems = []
    for module_name, names, page, slug, where in backlinks:
        if not (DOCS / page).exists() or slug not in slugs(DOCS / page):
            problems.append(f"{where}: docs/{page}#{slug} does not exist")
            continue
        obj = importlib.import_module(module_name)
        for name in names:
            obj = getattr(obj, name)
        implemented = {id(resolve(q)) for _, section, qs in index[page] if section == slug for q in qs}
        if id(obj) not in implemented:
            problems.append(f"{where}: no numbered equation in docs/{page}#{slug} names this object after 'Code:'")
    assert not problems, "\n".join(problems)
