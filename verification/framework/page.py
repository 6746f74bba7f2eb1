"""A report page described as data, and the one renderer that writes it as Markdown.

A case does not write Markdown: its ``report(result, out_dir)`` builds a :class:`Page` (a title and an ordered list
of sections: :class:`Heading`, :class:`Text`, :class:`Items`, :class:`Table`, :class:`Checks`, :class:`Figure`) and
hands it to :func:`write_page`, which renders every page the same way: sections separated by a blank line, table cells
with their pipes escaped (:func:`verification.framework.common.cell`), the checks as the one checks table
(:func:`verification.framework.common.checks_table`), the file written atomically. Cells are strings: the case
formats its numbers.
"""

from dataclasses import dataclass, field
from pathlib import Path

from mpmref.io.atomic import write_text_atomic

from .common import cell, checks_table


@dataclass(frozen=True)
class Heading:
    """A section heading (``## text``; ``level`` the number of ``#``)."""

    text: str
    level: int = 2

    def markdown(self):
        return f"{'#' * self.level} {self.text}"


@dataclass(frozen=True)
class Text:
    """A paragraph, as Markdown (inline code, emphasis and links are kept; nothing is escaped)."""

    text: str

    def markdown(self):
        return self.text


@dataclass(frozen=True)
class Items:
    """A bulleted list of ``items``; ``empty``, the paragraph said when there is none."""

    items: tuple
    empty: str = "(none)"

    def markdown(self):
        return "\n".join(f"- {item}" for item in self.items) if self.items else self.empty


@dataclass(frozen=True)
class Table:
    """A table: ``header``, the column names, and ``rows``, each a sequence of cells (strings, or anything ``str``
    writes as the case wants it)."""

    header: tuple
    rows: tuple

    def markdown(self):
        lines = [_row(self.header), "|" + "---|" * len(self.header)]
        return "\n".join(lines + [_row(r) for r in self.rows])


@dataclass(frozen=True)
class Checks:
    """The table of a case's checks (:func:`verification.framework.common.checks_table`)."""

    checks: tuple

    def markdown(self):
        return checks_table(self.checks)


@dataclass(frozen=True)
class Figure:
    """An image: ``path`` relative to the page, ``alt`` its alternative text."""

    path: str
    alt: str

    def markdown(self):
        return f"![{self.alt}]({self.path})"


@dataclass
class Page:
    """A report page: its ``title`` (the page's ``#`` heading) and its ``sections`` in order."""

    title: str
    sections: list = field(default_factory=list)

    def add(self, *sections):
        """Append ``sections`` in order; returns the page."""
        self.sections.extend(sections)
        return self


def _row(cells):
    return "| " + " | ".join(cell(c) for c in cells) + " |"


def page_markdown(page):
    """The Markdown text of ``page``: its title, then each section, separated by blank lines.

    Parameters
    ----------
    page : Page
        The page.

    Returns
    -------
    str
        The text, ending in a newline.
    """
    return "\n\n".join([f"# {page.title}"] + [s.markdown() for s in page.sections]) + "\n"


def write_page(page, path):
    """Write ``page`` as Markdown to ``path`` atomically (:func:`page_markdown`).

    Parameters
    ----------
    page : Page
        The page.
    path : str or pathlib.Path
        The Markdown file written.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    write_text_atomic(path, page_markdown(page))
    return Path(path)
