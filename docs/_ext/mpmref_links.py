"""Links from the chapters to the code, and back, resolved when the site is built.

The chapters link to code the way GitHub shows it:
``[`mpmref.physics.kernels.compute_stencil`](../mpmref/physics/kernels.py)`` (link text: the object's
qualified name; target: its source file). In the built site this extension points
such a link at the object's first line in the rendered source (``sphinx.ext.viewcode``), so that one
click on an equation's implementation link shows the code. A link to a Python file without a qualified
name opens the file's rendered source; a link to any other file in the repository (an example scene) opens
a copy of the file placed beside the site. A qualified name that does not name an object defined in the
linked file, or a file that does not exist, is a build error.

Back-links: in a docstring paragraph that starts with ``Docs:``, each ``docs/PAGE.md#anchor`` becomes a link
to that section of the site, both on the API page and in the rendered source.
"""

import ast
import posixpath
import re
import shutil
from pathlib import Path

from docutils import nodes
from sphinx import addnodes
from sphinx.pycode import ModuleAnalyzer
from sphinx.util import logging

logger = logging.getLogger(__name__)
QUALNAME = re.compile(r"^(mpmref|verification|exercises)(\.\w+)+$")
BACKLINK = re.compile(r"docs/(\w+)\.md#([\w-]+)")


def module_of(repo_path):
    """``mpmref/physics/kernels.py`` -> ``mpmref.physics.kernels`` (packages: their ``__init__``)."""
    parts = list(Path(repo_path).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def anchor_in(qualname, module, path):
    """The viewcode anchor of ``qualname`` in ``module``'s rendered source: the object's name inside the
    module (``NumpyBackend.stress``), or "" for the module itself or a module-level constant (the page's
    top). None when the source of ``module`` does not define it. A public path that re-exports an object
    from a submodule (``mpmref.conformance.check``, defined in ``mpmref.conformance.report``) lands on
    the definition. Read from the file ``path`` with Sphinx's own analyser, so nothing is imported."""
    if qualname == module:
        return ""
    package = module
    while package and not qualname.startswith(package + "."):
        package = package.rpartition(".")[0]
    if not package:
        return None
    inside = qualname[len(package) + 1:]
    analyzer = ModuleAnalyzer.for_file(str(path), module)
    if inside in analyzer.find_tags():
        return inside
    analyzer.analyze()
    return "" if ("", inside) in analyzer.attr_docs or inside in top_level_names(analyzer.code) else None


def top_level_names(code):
    names = set()
    for node in ast.parse(code).body:
        if isinstance(node, ast.Assign):
            names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return names


def rewrite_code_links(app, doctree):
    """Replace MyST's download links to repository files (``../mpmref/x.py``) by links into the site."""
    docname = app.env.docname
    root = Path(app.confdir).parent
    source_dir = Path(app.env.doc2path(docname)).parent
    to_root = posixpath.relpath(".", posixpath.dirname(docname)) if "/" in docname else "."
    for ref in list(doctree.findall(addnodes.download_reference)):
        target = (source_dir / ref["reftarget"]).resolve()
        try:
            repo_path = target.relative_to(root).as_posix()
        except ValueError:
            logger.warning("link %s leaves the repository", ref["reftarget"], location=ref)
            continue
        if not target.is_file():
            continue  # Sphinx itself reports a missing download target
        text = ref.astext()
        if target.suffix == ".py":
            module = module_of(repo_path)
            inside = anchor_in(text, module, target) if QUALNAME.match(text) else ""
            if inside is None:
                logger.warning("%s is not defined in %s", text, repo_path, location=ref)
                continue
            if target.name == "__init__.py" and not inside:
                uri = f"{to_root}/api/{module}.html"  # a package: its API page lists its modules
            else:
                uri = f"{to_root}/_modules/{module.replace('.', '/')}.html" + (f"#{inside}" if inside else "")
                app.env.mpmref_code_links.add((docname, module, inside))
        else:
            uri = f"{to_root}/_repo/{repo_path}"
            app.env.mpmref_repo_files.add(repo_path)
        ref.replace_self(nodes.reference("", "", *ref.children, refuri=uri, internal=True))


def init_env(app, env, docnames):
    for name in ("mpmref_code_links", "mpmref_repo_files"):
        if not hasattr(env, name):
            setattr(env, name, set())
    env.mpmref_code_links = {link for link in env.mpmref_code_links if link[0] not in docnames}


FIELD_SECTIONS = {"Parameters", "Other Parameters", "Attributes", "Returns", "Yields", "Raises"}
COMPACT_FIELD = re.compile(r"^(\S.*?\S)\s{2,}(\S.*)$")


def compact_fields(app, what, name, obj, options, lines):
    """Give napoleon the numpydoc layout of the sources' compact fields.

    The sources often write a field on one line, ``tau : (n, d, d) array   Kirchhoff stress``, or a group
    without a type, ``index, domain   as in validate_trimesh``, with continuation lines aligned under
    the description. numpydoc wants the description on its own indented lines; this moves it there (the
    text is unchanged) so that the rendered field shows name, type and description apart.
    """
    out, section, indent = [], None, 0
    for index, line in enumerate(lines):
        stripped = line.strip()
        following = lines[index + 1].strip() if index + 1 < len(lines) else ""
        if stripped and following and set(following) == {"-"} and len(following) >= len(stripped):
            section, indent = stripped, len(line) - len(line.lstrip())
            out.append(line)
            continue
        if section in FIELD_SECTIONS and stripped and not set(stripped) == {"-"}:
            depth = len(line) - len(line.lstrip())
            match = COMPACT_FIELD.match(stripped)
            if depth == indent and match:
                out += [" " * indent + match.group(1), " " * (indent + 4) + match.group(2)]
                continue
            if depth > indent:
                out.append(" " * (indent + 4) + stripped)
                continue
            if depth < indent:
                section = None
        out.append(line)
    lines[:] = out


def backlinks_in_docstring(app, what, name, obj, options, lines):
    """The paragraph ``Docs: docs/PAGE.md#anchor, ...`` of a docstring -> links to those sections."""
    in_docs = False
    for index, line in enumerate(lines):
        in_docs = line.strip().startswith("Docs:") or (in_docs and line.strip() != "")
        if in_docs:
            lines[index] = BACKLINK.sub(lambda m: f":docs-section:`{m.group(1)}#{m.group(2)}`", line)


def docs_section_role(name, rawtext, text, lineno, inliner, options=None, content=None):
    """``:docs-section:`page#slug``` -> a reference, resolved to the page's heading in ``resolve_sections``."""
    page, _, slug = text.partition("#")
    ref = nodes.reference(rawtext, f"docs/{page}.md#{slug}", refuri="", internal=True)
    ref["mpmref_section"] = (page, slug)
    return [ref], []


def resolve_sections(app, doctree, docname):
    """Point each back-link at its heading's id (MyST's GitHub-style slug -> the section id)."""
    for ref in doctree.findall(nodes.reference):
        if "mpmref_section" not in ref:
            continue
        page, slug = ref["mpmref_section"]
        slugs = app.env.metadata.get(page, {}).get("myst_slugs", {})
        if slug not in slugs:
            logger.warning("%s: back-link to docs/%s.md#%s: no such page or heading", docname, page, slug,
                           location=ref)
            continue
        ref["refuri"] = app.builder.get_relative_uri(docname, page) + "#" + slugs[slug][1]


def backlinks_in_source_pages(app, pagename, templatename, context, doctree):
    """In the rendered source (``_modules/...``), ``docs/PAGE.md#anchor`` in a docstring links to that
    section too, so the way back from a line of code to its equation is one click."""
    if not pagename.startswith("_modules/") or "body" not in context:
        return

    def link(match):
        page, slug = match.group(1), match.group(2)
        slugs = app.env.metadata.get(page, {}).get("myst_slugs", {})
        if slug not in slugs:
            logger.warning("%s: back-link to docs/%s.md#%s: no such page or heading", pagename, page, slug)
            return match.group(0)
        uri = posixpath.relpath(page, posixpath.dirname(pagename)) + ".html#" + slugs[slug][1]
        return f'<a href="{uri}">{match.group(0)}</a>'

    context["body"] = BACKLINK.sub(link, context["body"])


def check_code_anchors(app, exception):
    """Every code link lands on a rendered source page, and on the object's anchor there."""
    if exception is not None or app.builder.format != "html":
        return
    for docname, module, inside in sorted(app.env.mpmref_code_links):
        page = Path(app.outdir) / "_modules" / (module.replace(".", "/") + ".html")
        if not page.exists():
            logger.warning("%s: no rendered source for %s (is it in the API reference?)", docname, module)
        elif inside and f'id="{inside}"' not in page.read_text(encoding="utf-8"):
            logger.warning("%s: the source page of %s has no anchor for %s (documented in the API?)",
                           docname, module, inside)


def copy_repo_files(app, exception):
    if exception is not None or app.builder.format != "html":
        return
    root = Path(app.confdir).parent
    for repo_path in sorted(app.env.mpmref_repo_files):
        out = Path(app.outdir) / "_repo" / repo_path
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(root / repo_path, out)


def setup(app):
    app.connect("env-before-read-docs", init_env)
    app.connect("doctree-read", rewrite_code_links, priority=400)  # before Sphinx collects downloads
    app.connect("autodoc-process-docstring", compact_fields, priority=400)  # before napoleon reads them
    app.connect("autodoc-process-docstring", backlinks_in_docstring)
    app.add_role("docs-section", docs_section_role)
    app.connect("doctree-resolved", resolve_sections)
    app.connect("html-page-context", backlinks_in_source_pages)
    app.connect("build-finished", copy_repo_files)
    app.connect("build-finished", check_code_anchors)
    # the links collected while reading live in two sets on the environment, not merged across processes
    return {"version": "1", "parallel_read_safe": False, "parallel_write_safe": True}
