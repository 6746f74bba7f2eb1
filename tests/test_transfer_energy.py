"""The transfer-only energy study (verification/transfer_energy.py) in its quick preset."""

from dataclasses import replace

import pytest
from helpers import assert_every_figure_has_a_caption

from verification import transfer_energy as case
from verification.framework.common import failed


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


def test_every_theory_check_holds(result):
    failing = [c.line() for c in failed(case.checks(result))]
    assert not failing, "\n".join(failing)


def test_a_broken_input_makes_a_check_fail(result):
    """If PolyPIC had dropped its higher modes (i.e. were APIC), its fixed-point check must fail."""
    broken = {"params": result["params"], "rows": [dict(r) for r in result["rows"]]}
    apic_rows = {r["wavelength_cells"]: r for r in broken["rows"] if r["scheme"] == "apic"}
    for r in broken["rows"]:
        if r["scheme"] == "polypic":
            r.update({k: v for k, v in apic_rows[r["wavelength_cells"]].items() if k != "scheme"})
    failing = [c.name for c in failed(case.checks(broken))]
    assert any("PolyPIC change per cycle" in name for name in failing)


def test_cubic_kernel_study_also_holds():
    res = case.run(replace(case.Params.quick(), kernel="cubic", cycles=4))
    assert all(c.passed for c in case.checks(res))


def test_report_writes_the_plot_and_the_table(result, tmp_path):
    figure, table = case.report(result, tmp_path)
    assert figure.name == case.MAIN_FIGURE
    text = table.read_text()
    assert "| polypic |" in text and "pass" in text
    assert_every_figure_has_a_caption(tmp_path)
