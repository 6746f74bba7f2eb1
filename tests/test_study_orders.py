"""What a study says of its orders: a fitted order from two errors says it is the line through two points
(in its row of results.json, the summary line and index.html), and a row whose fitted order and Richardson's estimate
differ by 0.5 or more says so in its note, with the reason."""

import json
import math

import numpy as np
import pytest

from verification.study import Variation
from verification.study.cli import summary
from verification.study.orders import DISAGREEMENT, TWO_POINTS, disagreement, observed_orders, order
from verification.study.report import index_html, results

EPS = np.finfo(float).eps


def synthetic(h, values, exact=None):
    return [{"abscissa": {"k": ("h", x)}, "metrics": {"q": q}, "exact": {} if exact is None else {"q": exact}}
            for x, q in zip(h, values)]


def test_a_fit_through_two_errors_says_it_is_the_line_through_two_points():
    """Three levels against the finest run, or two against the exact value, leave two errors; more leave more."""
    h = np.array([0.1, 0.05, 0.025, 0.0125])
    assert order(synthetic(h[:3], 1.0 + h[:3]), "k", "q", EPS)["fit"] == TWO_POINTS
    assert order(synthetic(h[:2], 1.0 + h[:2], exact=1.0), "k", "q", EPS)["fit"] == TWO_POINTS
    assert order(synthetic(h, 1.0 + h), "k", "q", EPS)["fit"] == "the least-squares line through 3 points"
    assert order(synthetic(h, 1.0 + h, exact=1.0), "k", "q", EPS)["fit"] == "the least-squares line through 4 points"
    no_fit = order(synthetic(h[:2], 1.0 + h[:2]), "k", "q", EPS)  # one error against the finest run: no fit
    assert math.isnan(no_fit["order"]) and no_fit["fit"] == ""


def test_against_the_finest_run_a_fit_half_an_order_off_richardson_says_to_trust_richardson():
    """First order on three levels halving h: the fit reads log2(3) = 1.58, Richardson's estimate 1."""
    row = order(synthetic(np.array([0.1, 0.05, 0.025]), 1.0 + np.array([0.1, 0.05, 0.025])), "k", "q", EPS)
    assert row["note"] == ("the fitted order, 1.58, and Richardson's estimate, 1.00, differ by 0.58: against the "
                           "finest run the fit reads high on few levels (each error carries the finest run's own: "
                           "first order reads 1.58 on three levels halving h), so trust Richardson's")


def test_against_the_exact_value_a_fit_half_an_order_off_richardson_names_the_coarse_levels():
    """Errors 1, 0.1, 0.05, 0.025 on h halving: the coarsest level is far from first order, which the three finest
    (Richardson's) show; the fit over all four reads 1.70."""
    row = order(synthetic(np.array([0.4, 0.2, 0.1, 0.05]), [1.0, 0.1, 0.05, 0.025], exact=0.0), "k", "q", EPS)
    assert row["richardson"] == pytest.approx(1.0, abs=1e-12) and row["order"] == pytest.approx(1.6966, abs=1e-4)
    assert "differ by 0.70: the coarse levels, which the fit uses and Richardson's estimate does not, are not in " \
           "the asymptotic range" in row["note"]


@pytest.mark.parametrize("fitted, estimate, noted", [(1.0, 1.0 + DISAGREEMENT, True), (1.0, 1.499, False),
                                                     (2.0, 1.5, True), (1.0, math.nan, False)])
def test_the_note_starts_at_half_an_order_apart(fitted, estimate, noted):
    assert bool(disagreement(fitted, estimate, "exact")) is noted


def test_orders_that_agree_get_no_note():
    h = np.array([0.1, 0.05, 0.025, 0.0125])
    row = order(synthetic(h, 3.0 + 0.7 * h**2, exact=3.0), "k", "q", EPS)
    assert row["note"] == "" and abs(row["order"] - row["richardson"]) < 1e-9


@pytest.fixture
def three_grid_study():
    """A study of three grids of a first-order measure, as run_study returns it (no run is made)."""
    runs = [{"params": {"grid.cells": c}, "abscissa": {"grid.cells": ("Δx", 1.0 / c)}, "exact": {}, "error": None,
             "reused": False, "id": str(c), "result": f"runs/{c}.json", "metrics": {"energy_change": 1.0 + 1.0 / c}}
            for c in (16, 32, 64)]
    orders = observed_orders(runs, [Variation.of("grid.cells", [16, 32, 64])], ["energy_change"], EPS)
    meta = {"scene_name": "s", "scene": "s.toml", "vary": [{"keys": ["grid.cells"], "levels": [[16], [32], [64]]}],
            "t_end": 1.0, "machine": {}, "backend": {"backend": "numpy", "execution": None}}
    return {**meta, "runs": runs, "orders": orders, "wall_s": 1.0, "paths": ["index.html"]}


def test_the_summary_line_says_the_fit_is_through_two_points_and_how_far_it_is_from_richardson(three_grid_study):
    line = next(li for li in summary(three_grid_study).splitlines() if li.startswith("order of energy_change"))
    assert line.endswith("fitted 1.585 (the line through two points), Richardson 1.000; they differ by 0.585 (the "
                         "note in index.html says why)")


def test_results_json_and_index_html_say_the_fit_is_through_two_points(three_grid_study, tmp_path):
    meta = {k: v for k, v in three_grid_study.items() if k not in ("runs", "orders", "wall_s", "paths")}
    row = json.loads(json.dumps(results(meta, three_grid_study["runs"], three_grid_study["orders"])))["orders"][0]
    assert row["fit"] == TWO_POINTS and "differ by 0.58" in row["note"]
    page = index_html(meta, three_grid_study["runs"], three_grid_study["orders"], [], tmp_path)
    assert f"<td class='num'>1.585<br><small>{TWO_POINTS}</small></td>" in page
    assert "so trust Richardson&#x27;s" in page
