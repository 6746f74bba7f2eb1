"""Build the documentation site and open it: ``python docs/build.py`` (needs ``pip install -e '.[docs]'``).

Runs Sphinx on this folder from a clean environment with warnings as errors (``-E -W --keep-going``), so a
broken internal link, a heading anchor that does not exist, an equation link whose function moved, or a
docstring that does not parse fails the build. The site goes to ``docs/_build/html`` (or ``--out DIR``)
and opens in the browser unless ``--no-open`` is given. Exit status: Sphinx's (0 when the site is clean).
"""

import argparse
import shutil
import sys
import webbrowser
from pathlib import Path

DOCS = Path(__file__).resolve().parent


def build(out, open_browser=True):
    """Build the site into ``out``; returns Sphinx's exit status."""
    try:
        from sphinx.cmd.build import build_main
    except ImportError:
        print("the docs build needs Sphinx: pip install -e '.[docs]'", file=sys.stderr)
        return 2
    shutil.rmtree(DOCS / "api", ignore_errors=True)   # generated per module by autosummary; rebuilt fresh
    if (Path(out) / ".buildinfo").exists():           # an earlier site: the source pages are only
        shutil.rmtree(out)                            # rewritten when stale, so start from nothing
    status = build_main(["-E", "-W", "--keep-going", "-q", "-b", "html", str(DOCS), str(out)])
    if status == 0:
        index = Path(out).resolve() / "index.html"
        print(f"built {index}")
        if open_browser:
            webbrowser.open(index.as_uri())
    return status


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(DOCS / "_build" / "html"), help="output folder")
    parser.add_argument("--no-open", action="store_true", help="do not open the site in a browser")
    args = parser.parse_args(argv)
    return build(args.out, open_browser=not args.no_open)


if __name__ == "__main__":
    sys.exit(main())
