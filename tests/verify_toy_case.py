"""A toy verification case for the report tests (``tests/test_verify_report.py``).

It measures nothing: its "result" is the parameters, so that the tests know every figure the report must
show. Two checks (the first fails when ``slope`` exceeds 2.5; the second has an infinite bound, which
``results.json`` must still encode), one finding, one captioned figure and one without a caption. It
declares that it ran two backends, as the cases that compare backends do.
"""

from dataclasses import dataclass
from pathlib import Path

from verification.framework.case import VerificationCase
from verification.framework.common import Check, Finding
from verification.framework.report import pyplot, save_figure

#: the figure index.html shows for this case
MAIN_FIGURE = "line.png"
CAPTION = ("A straight line of the chosen slope through the origin. Look for the slope: it is the figure "
           "that the first check holds to 2.5.")


@dataclass(frozen=True)
class Params:
    slope: float = 2.0

    @classmethod
    def quick(cls):
        return cls()

    @classmethod
    def full(cls):
        return cls()


def run(params, backend="numpy", executor=None):
    return {"slope": params.slope, "backend": backend}


def backends_run(result, backend):
    return (result["backend"], "numba")


def checks(result):
    return [Check("slope of the line", result["slope"], "<=", 2.5, "the toy's theory allows up to 2.5"),
            Check("a value below an infinite bound", 1.0, "<", float("inf"), "nothing is infinite here")]


def findings(result):
    return [Finding("curvature of the line", 0.0, "The line is straight: measured, not judged.")]


def report(result, out_dir):
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for name, caption in (("line.png", CAPTION), ("uncaptioned.png", None)):
        fig, ax = pyplot().subplots()
        ax.plot([0.0, 1.0], [0.0, result["slope"]])
        save_figure(fig, out / name, caption=caption)
    return out


CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings, backends_run=backends_run,
                        main_figure=MAIN_FIGURE)
