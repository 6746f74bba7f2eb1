"""Shared pieces of verification cases: named checks with their bound and verdict, and findings.

A case's ``checks(result)`` returns :class:`Check` objects (a figure held to a bound derived from
theory); its ``findings(result)`` returns :class:`Finding` objects (a measured figure that is reported,
not judged: behaviour worth knowing that is not a failure; see :class:`verification.framework.case.VerificationCase`).
"""

from dataclasses import dataclass


@dataclass(frozen=True)
class Check:
    """One named figure of a case, the bound it is held to, and whether it holds.

    ``relation`` says how ``value`` is compared with ``bound``: ``"<="``, ``">="``, ``"<"`` or ``">"``.
    """

    name: str
    value: float
    relation: str
    bound: float
    reason: str

    @property
    def passed(self):
        ops = {"<=": lambda a, b: a <= b, ">=": lambda a, b: a >= b, "<": lambda a, b: a < b, ">": lambda a, b: a > b}
        return bool(ops[self.relation](self.value, self.bound))

    def line(self, case=None):
        """The check as a row of a Markdown table (:func:`check_header`), its texts' pipes escaped; ``case`` a first
        cell."""
        cells = [] if case is None else [cell(case)]
        cells += [cell(self.name), f"{self.value:.6g}", f"{self.relation} {self.bound:.6g}",
                  "pass" if self.passed else "FAIL", cell(self.reason)]
        return "| " + " | ".join(cells) + " |"


@dataclass(frozen=True)
class Finding:
    """A measured figure of a case that is reported, not judged.

    Attributes
    ----------
    name : str
        What was measured, e.g. ``"bar: MLS-MPM quadratic: fitted slope of e_u"``.
    value : float
        The measured figure.
    sentence : str
        One sentence saying what the figure shows and why it is not a failure.
    """

    name: str
    value: float
    sentence: str


def cell(text):
    """Markdown table cell text: pipes escaped, so a check named ``|P|`` cannot split the row."""
    return str(text).replace("|", "\\|")


def check_header(with_case=False):
    """The header rows of a Markdown table of checks (:meth:`Check.line`), with a first ``case`` column or not."""
    head = ["case"] * with_case + ["check", "figure", "bound", "verdict", "why this bound"]
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]


def checks_table(checks):
    """A Markdown table of ``checks``: the one renderer of the case reports and the index."""
    return "\n".join(check_header() + [c.line() for c in checks])


def failed(checks):
    """The checks of ``checks`` that do not hold, in order."""
    return [c for c in checks if not c.passed]


def backend_sentence(meta):
    """The backend under test, as the report names it: its reference, class and version (``meta["backend"]``,
    :func:`mpmref.backends.describe`), or ``""`` when the caller did not describe it."""
    backend = meta.get("backend")
    if not backend:
        return ""
    version = f"version {backend['version']}" if backend["version"] else "no version given"
    scene = f" The checks of the scene `{meta['scene']}` (`mpmref verify --scene`)." if meta.get("scene") else ""
    return f"Backend under test: `{backend['backend']}` ({backend['class']}, {version}).{scene}"


def verdict_word(summary):
    """``PASS`` when every check that ran passes and no case stopped with an error, ``FAIL`` otherwise, ``NOTHING
    CHECKED`` when no check applied at all."""
    if summary["failing"] or summary["errors"]:
        return "FAIL"
    return "PASS" if summary["checks"] else "NOTHING CHECKED"


def summary_sentence(summary):
    """The counts of a report in words: checks passing and failing, not applicable items, errors, findings."""
    passing = summary["checks"] - summary["failing"]
    applicable = summary["cases"] - summary["cases_not_applicable"]
    return (f"{passing} of {summary['checks']} checks pass, {summary['failing']} fail, in {applicable} of "
            f"{summary['cases']} cases; {summary['not_applicable']} not applicable to this backend (checks or runs, "
            f"each with its reason; {summary['cases_not_applicable']} cases wholly); {summary['errors']} cases "
            f"stopped with an error; {summary['findings']} findings (measured, not judged)")
