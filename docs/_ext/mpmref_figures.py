"""Sphinx extension: the figures of the verification cases, made at build time by the cases themselves.

When the build starts, every case of :data:`FIGURE_CASES` runs its quick preset on the NumPy reference
(:func:`verification.registry.run_case`) into ``docs/_generated/CASE/``, and a Markdown fragment
``docs/_generated/CASE.md`` lists its PNG plots, each with the caption the case stored in the PNG
(:func:`verification.report.figure_caption`). ``figures.md`` includes the fragments, so a figure in the
site is what the code does today, never a hand-made picture. A case whose checks fail, or that stops with
an error, fails the build (a warning, and the site builds with warnings as errors).
"""

import shutil
from pathlib import Path

from sphinx.util import logging

#: the cases whose quick-preset plots the site shows (figures.md includes one fragment per case)
FIGURE_CASES = ("momentum", "energy", "convergence", "extremes", "cpic")

log = logging.getLogger(__name__)


def fragment(name, title, folder):
    """Markdown listing the PNGs of one case's report folder with their stored captions."""
    from verification.report import figure_caption

    lines = [f"## {title}", ""]
    for png in sorted(folder.glob("*.png")):
        caption = figure_caption(png) or png.stem.replace("_", " ")
        lines += [f"![{png.stem}](/_generated/{name}/{png.name})", "", f"*{caption}*", ""]
    return "\n".join(lines)


def generate(app):
    """Run each case of :data:`FIGURE_CASES` (quick preset) and write its fragment."""
    from verification import registry

    out = Path(app.srcdir) / "_generated"
    shutil.rmtree(out, ignore_errors=True)
    for name in FIGURE_CASES:
        log.info(f"mpmref figures: running the {name} case (quick preset)")
        outcome = registry.run_case(name, "quick", "numpy", out_dir=out / name)
        if not outcome.passed:
            why = outcome.error.strip().splitlines()[-1] if outcome.error else "a check failed"
            log.warning(f"mpmref figures: the {name} case did not pass ({why}); its figures are not shown")
        (out / f"{name}.md").write_text(fragment(name, outcome.title, out / name), encoding="utf-8")


def setup(app):
    app.connect("builder-inited", generate)
    return {"version": "1", "parallel_read_safe": True}
