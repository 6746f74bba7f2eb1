"""The documentation site: every page is in its table of contents, and it builds with warnings as errors.

The fast checks need no Sphinx. The full build (``docs/build.py``: Sphinx, MyST-Parser, autodoc, viewcode,
warnings as errors, every code link landing on its object's line) runs when the ``docs`` extra is
installed (``pip install -e '.[docs]'``) and is skipped otherwise; run it with
``.venv/bin/python -m pytest tests/test_docs_site.py``.
"""

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
HAS_SPHINX = all(importlib.util.find_spec(m) is not None for m in ("sphinx", "myst_parser"))


def toctree_entries():
    text = (DOCS / "index.md").read_text(encoding="utf-8")
    block = re.search(r"^```\{toctree\}\n(.*?)^```", text, re.MULTILINE | re.DOTALL)
    assert block, "docs/index.md has no {toctree} block"
    return [line.strip() for line in block.group(1).splitlines() if line.strip() and not line.startswith(":")]


def test_every_page_is_in_the_table_of_contents_once():
    entries = toctree_entries()
    pages = sorted(p.stem for p in DOCS.glob("*.md") if p.stem != "index")
    assert sorted(entries) == pages, "docs/index.md's toctree must list every page of docs/ exactly once"


@pytest.mark.skipif(not HAS_SPHINX, reason="the docs extra is not installed: pip install -e '.[docs]'")
def test_site_builds_with_warnings_as_errors(tmp_path):
    out = tmp_path / "html"
    run = subprocess.run([sys.executable, str(DOCS / "build.py"), "--no-open", "--out", str(out)],
                         capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 0, run.stdout + run.stderr
    # one equation's implementation link lands on the function's line in the rendered source
    cycle = (out / "mls_vs_classic.html").read_text(encoding="utf-8")
    assert 'href="./_modules/mpmref/backends/numpy/transfers.html#mls_gradient_weight"' in cycle
    source = (out / "_modules" / "mpmref" / "backends" / "numpy" / "transfers.html").read_text(encoding="utf-8")
    assert 'id="mls_gradient_weight"' in source
