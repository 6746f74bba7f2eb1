"""Build the documentation site and open it: ``python docs/build.py`` (needs ``pip install -e '.[docs]'``).

Runs Sphinx on this folder from a clean environment with warnings as errors (``-E -W --keep-going``), so a
broken internal link, a heading anchor that does not exist, an equation link whose function moved, or a
docstring that does not parse fails the build. The site goes to ``docs/_build/html`` (or ``--out DIR``)
and opens in the browser unless ``--no-open`` is given. While it builds, a line on standard error says what it
is doing and for how long it has run (:class:`Progress`: the figures each case and study makes, then Sphinx's
phases; ``--no-progress`` turns them off). Exit status: Sphinx's (0 when the site is clean).
"""

import argparse
import contextlib
import io
import re
import shutil
import sys
import time
import webbrowser
from pathlib import Path

DOCS = Path(__file__).resolve().parent
#: the start of the lines the site's own extensions log (docs/_ext): each is shown
OWN = "mpmref"
#: a line of Sphinx's counted phases, ``reading sources... [ 42%] api/mpmref``: its phase and percentage
COUNTED = re.compile(r"^(?P<phase>[^\[]*?)\.\.\. \[\s*(?P<percent>\d+)%\]")
#: how many progress lines each counted phase gets at most: its start, then every quarter
QUARTERS = 4
#: the longest progress line shown (Sphinx's own lines can run to thousands of characters)
WIDTH = 110


class Progress(io.TextIOBase):
    """Sphinx's status output cut to a few progress lines on ``stream``, each with the seconds since the start.

    A line of the site's own extensions (:data:`OWN`, the figures each verification case and study makes, most of
    the build's time) is shown whole; of Sphinx's own, the first of each phase (:func:`phase_of`), and of a counted
    phase (:data:`COUNTED`, e.g. reading the pages) the first line in each quarter of the count.
    """

    def __init__(self, stream, clock=time.monotonic):
        self.stream, self.clock, self.start = stream, clock, clock()
        self.pending, self.last = "", None

    def write(self, text):
        *lines, self.pending = re.split(r"[\r\n]", self.pending + text)
        for line in lines:
            self.show(line.strip())
        return len(text)

    def show(self, line):
        """Print ``line`` if it starts a phase, a quarter of a counted one, or is the site's own."""
        if not line:
            return
        phase = phase_of(line)
        if line.startswith(OWN) or phase != self.last:
            shown = line if len(line) <= WIDTH else line[:WIDTH - 1] + "…"
            print(f"docs {self.clock() - self.start:5.0f} s  {shown}", file=self.stream, flush=True)
        self.last = phase


def phase_of(line):
    """What ``line`` of Sphinx's status output is a step of: in a counted phase, the phase and the quarter; otherwise
    the first three words before any ``...`` or ``:``."""
    counted = COUNTED.match(line)
    if counted:
        return counted["phase"], min(int(counted["percent"]) * QUARTERS // 100, QUARTERS - 1)
    return tuple(re.split(r"\.\.\.|:", line, maxsplit=1)[0].split()[:3])


def build(out, open_browser=True, progress=True):
    """Build the site into ``out``, with progress lines on standard error (:class:`Progress`) unless not
    ``progress``; returns Sphinx's exit status."""
    try:
        from sphinx.cmd.build import build_main
    except ImportError:
        print("the docs build needs Sphinx: pip install -e '.[docs]'", file=sys.stderr)
        return 2
    shutil.rmtree(DOCS / "api", ignore_errors=True)   # generated per module by autosummary; rebuilt fresh
    if (Path(out) / ".buildinfo").exists():           # an earlier site: the source pages are only
        shutil.rmtree(out)                            # rewritten when stale, so start from nothing
    options = ["-E", "-W", "--keep-going", "-b", "html"] + ([] if progress else ["-q"])
    with contextlib.redirect_stdout(Progress(sys.stderr)):  # Sphinx writes its status to standard output
        status = build_main(options + [str(DOCS), str(out)])
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
    parser.add_argument("--no-progress", action="store_true", help="no progress lines (on standard error)")
    args = parser.parse_args(argv)
    return build(args.out, open_browser=not args.no_open, progress=not args.no_progress)


if __name__ == "__main__":
    sys.exit(main())
