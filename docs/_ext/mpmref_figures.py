"""Sphinx extension: the figures of the verification cases and of the studies, made at build time by the code itself.

When the build starts, every case of :data:`FIGURE_CASES` runs its quick preset on the NumPy reference
(:func:`verification.framework.registry.run_case`) into ``docs/_generated/CASE/``, and a Markdown fragment
``docs/_generated/CASE.md`` lists its PNG plots, each with the caption the case stored in the PNG
(:func:`verification.framework.report.figure_caption`). ``figures.md`` includes the fragments, so a figure in the
site is what the code does today, never a hand-made picture. A case whose checks fail, or that stops with
an error, fails the build (a warning, and the site builds with warnings as errors). Likewise each study of
:data:`STUDIES` runs on ``docs/breathing_disk.toml`` (:func:`verification.study.run_study`, NumPy, a few
seconds in all) into ``docs/_generated/NAME/`` with its fragment ``NAME.md``, which
``studying_your_scene.md`` includes; a run that fails fails the build.
"""

import shutil
from pathlib import Path

from sphinx.util import logging

#: the cases whose quick-preset plots the site shows (figures.md includes one fragment per case)
FIGURE_CASES = ("momentum", "energy", "convergence", "extremes", "cpic")

#: the studies of studying_your_scene.md: name, title, what they vary and their other settings (the same as the
#: command lines the chapter shows)
STUDIES = (
    ("study_conservation", "The conservation study's figures",
     {"method.scheme": ["pic", "flip", "polypic", "mls"]}, {}),
    ("study_convergence", "The convergence study's figures", {"grid.cells": [16, 32, 64, 128]},
     {"measures": ["verification.study.measures:shape"], "ledger": False}),
)

log = logging.getLogger(__name__)


def fragment(name, title, folder, level=2):
    """Markdown listing the PNGs of one report folder with their stored captions, under a heading of ``level``."""
    from verification.framework.report import figure_caption

    lines = [f"{'#' * level} {title}", ""]
    for png in sorted(folder.glob("*.png")):
        caption = figure_caption(png) or png.stem.replace("_", " ")
        lines += [f"![{png.stem}](/_generated/{name}/{png.name})", "", f"*{caption}*", ""]
    return "\n".join(lines)


def generate(app):
    """Run each case of :data:`FIGURE_CASES` (quick preset) and write its fragment."""
    from verification.framework import registry

    out = Path(app.srcdir) / "_generated"
    shutil.rmtree(out, ignore_errors=True)
    for name in FIGURE_CASES:
        log.info(f"mpmref figures: running the {name} case (quick preset)")
        outcome = registry.run_case(name, "quick", "numpy", out_dir=out / name)
        if not outcome.passed:
            why = outcome.error.strip().splitlines()[-1] if outcome.error else "a check failed"
            log.warning(f"mpmref figures: the {name} case did not pass ({why}); its figures are not shown")
        (out / f"{name}.md").write_text(fragment(name, outcome.title, out / name), encoding="utf-8")
    generate_studies(out)


def generate_studies(out):
    """Run each study of :data:`STUDIES` on the chapter's scene and write its fragment."""
    from verification.study import run_study

    for name, title, vary, settings in STUDIES:
        log.info(f"mpmref figures: running the study {name}")
        study = run_study(Path(__file__).resolve().parent.parent / "breathing_disk.toml", vary, out=out / name,
                          **settings)
        failed = [r for r in study["runs"] if r["error"]]
        if failed:
            log.warning(f"mpmref figures: {len(failed)} run(s) of the study {name} failed "
                        f"({failed[0]['error'].strip().splitlines()[-1]}); its figures are not complete")
        (out / f"{name}.md").write_text(fragment(name, title, out / name, level=3), encoding="utf-8")


def setup(app):
    app.connect("builder-inited", generate)
    return {"version": "1", "parallel_read_safe": True}
