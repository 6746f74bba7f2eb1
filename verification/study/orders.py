r"""Observed orders of a study's measures, for every resolution it varies.

A *resolution* key sets the size :math:`h` of a discretisation: ``grid.cells`` and ``grid.dx`` the cell size
:math:`\Delta x`, ``time.dt`` the step :math:`\Delta t`, ``time.cfl`` the CFL number (the step in units of the
cell crossing time), ``bodies[i].ppc`` the particle spacing :math:`\mathrm{ppc}^{-1/d}` in cells. For each
``--vary`` with such a key (linked keys refine with it), the runs that share the values of the other keys form
a refinement series :math:`h_1 > h_2 > \dots > h_n`, and each measure :math:`q` gets

* the **fitted order**: the least-squares slope :math:`p` of :math:`\log e_k` against :math:`\log h_k`
  (:func:`verification.convergence.fit_slope`), with the error :math:`e_k = |q_k - q^*|` against the exact value
  :math:`q^*` where ``--exact`` gives one (every level), otherwise against the finest run,
  :math:`e_k = |q_k - q_n|` (levels :math:`1 \dots n-1`);
* **Richardson's estimate** from the three finest levels, for a constant ratio :math:`r = h_{n-2}/h_{n-1} =
  h_{n-1}/h_n` (the observed order of Roache 1998, *Verification and Validation in Computational Science and
  Engineering*, with its extrapolated value):

  .. math::

      p_R = \frac{\log\big(|q_{n-2} - q_{n-1}| \,/\, |q_{n-1} - q_n|\big)}{\log r}, \qquad
      q_R = q_n + \frac{q_n - q_{n-1}}{r^{p_R} - 1},

  where :math:`q_R` estimates the limit :math:`h \to 0`. It is undefined (with a note saying why) when the
  ratios differ, when two levels agree exactly, or when the differences change sign (the levels are not in the
  asymptotic range); values that are not monotone over all the levels are noted likewise.

Both assume :math:`q_k \approx q^* + C h_k^p`. Against the finest run each error carries the finest run's own,
:math:`e_k = C(h_k^p - h_n^p)`, which biases the fit upwards on few levels: on three levels halving :math:`h` the two
errors are in the ratio :math:`(4^p - 1)/(2^p - 1)`, so a first-order measure reads :math:`\log_2 3 = 1.58`.
Richardson's estimate has no such bias; with the exact value the fit has none either, and where the two then
disagree the levels are not yet in the asymptotic range. Where the two differ by :data:`DISAGREEMENT` or more, the
row's note says so and why (:func:`disagreement`). Two errors (three levels against the finest run, two against the
exact value) always lie on a line, so their slope shows nothing of whether the errors follow a power of :math:`h`:
the row says that its fit is :data:`TWO_POINTS`. Levels that agree to round-off (errors within
:data:`ROUND_OFF_EPS` machine epsilons of the values), and drifts that are round-off at every level, get no order.
A measure that cannot be negative (:data:`NON_NEGATIVE`: a norm, the largest :math:`|E(t) - E(0)|`) whose
extrapolated limit :math:`q_R` comes out negative has no limit resolved by its levels: its finest value is smaller
than the extrapolation's own estimate of its error, :math:`|q_n - q_R|`, so the limit is reported as missing with
a note giving both (a limit clipped at 0 would be a number no level measured).
"""

import math

import numpy as np

from ..convergence import fit_slope
from .runs import DRIFTS
from .variations import key_path, label

#: the built-in metrics that get orders (relative drifts: the rest are counts and timings)
ORDERED = DRIFTS[:3] + ("energy_excursion",)
#: a relative drift whose every level is below this many machine epsilons is round-off, not discretisation error
ROUND_OFF_EPS = 1.0e4
#: the built-in measures that cannot be negative (norms of a change, the largest relative change): their limit >= 0
NON_NEGATIVE = ("momentum_drift", "angular_momentum_drift", "energy_excursion")
#: what a fitted order is when only two errors are fitted: any two points fit a line
TWO_POINTS = "the line through two points"
#: the difference between the fitted order and Richardson's estimate from which a row's note points it out
DISAGREEMENT = 0.5


def abscissa(key, scene):
    """``(name, h)``: what refining ``key`` refines and its size in ``scene``; ``None`` for a key that is not a
    resolution (a material constant, a scheme)."""
    path = key_path(key)
    if path in (("grid", "cells"), ("grid", "dx")):
        return "Δx", scene.grid.dx
    if path == ("time", "dt"):
        return "Δt", scene.time.dt
    if path == ("time", "cfl"):
        return "CFL number", scene.time.cfl
    if len(path) == 3 and path[0] == "bodies" and path[2] == "ppc":
        return "particle spacing / Δx", scene.bodies[path[1]].params["ppc"] ** (-1.0 / scene.dim)
    return None


def observed_orders(runs, variations, measures, eps):
    """The order rows of a study.

    Parameters
    ----------
    runs : list of dict
        Each run's ``params``, ``abscissa`` (``{key: (name, h)}`` of its resolution keys), ``metrics`` (absent for a
        failed run) and ``exact`` (``{measure: value}``, maybe empty).
    variations : list of Variation
    measures : list of str
        The measures to order (:data:`ORDERED` and the user's).
    eps : float
        Machine epsilon of the scenes' dtype (:data:`ROUND_OFF_EPS`).

    Returns
    -------
    list of dict
        Per resolution key, series and measure: ``key``, ``abscissa``, ``refined_with`` (the keys linked to it),
        ``fixed`` (the other keys' values), ``measure``, ``against`` (``"exact"`` or ``"finest run"``), ``h``,
        ``values``, ``errors`` (``null`` where not measured), ``order``, ``fit`` (what ``order`` is the slope of:
        :func:`fitted_line`, ``""`` without one), ``intercept``, ``richardson``, ``extrapolated`` and ``note`` (why a
        figure is missing, where the two orders disagree, or ``""``).
    """
    done = [r for r in runs if "metrics" in r]
    rows = []
    for variation in variations:
        key = next((k for k in variation.keys if done and k in done[0]["abscissa"]), None)
        if key is None:
            continue
        others = [k for v in variations if v is not variation for k in v.keys]
        for fixed, series in _series(done, key, others):
            for name in measures:
                if all(name in r["metrics"] for r in series):
                    rows.append({"key": key, "abscissa": series[0]["abscissa"][key][0],
                                 "refined_with": [k for k in variation.keys if k != key], "fixed": fixed,
                                 "measure": name, **order(series, key, name, eps, drift=name in ORDERED,
                                                          non_negative=name in NON_NEGATIVE)})
    return rows


def _series(runs, key, others):
    """``(fixed, runs)`` per refinement series: the runs sharing the values of ``others``, coarse to fine."""
    groups = {}
    for run in runs:
        fixed = {k: run["params"][k] for k in others}
        groups.setdefault(repr(fixed), (fixed, []))[1].append(run)
    return [(fixed, sorted(rs, key=lambda r: -r["abscissa"][key][1])) for fixed, rs in groups.values() if len(rs) >= 2]


def order(series, key, name, eps, drift=False, non_negative=False):
    """The fitted order and Richardson's estimate of measure ``name`` over one refinement ``series`` (the module
    docstring). Errors within :data:`ROUND_OFF_EPS` machine epsilons ``eps`` of the values are round-off, as is a
    relative ``drift`` whose every value is that small: then there is no order to measure. A ``non_negative``
    measure's negative extrapolated limit is not resolved (:func:`unresolved_limit`)."""
    h = np.array([r["abscissa"][key][1] for r in series])
    q = np.array([float(r["metrics"][name]) for r in series])
    exact = [r["exact"].get(name) for r in series]
    against = "exact" if all(e is not None for e in exact) else "finest run"
    if against == "exact":
        errors, fit = np.abs(q - np.array(exact, dtype=np.float64)), slice(None)
    else:
        errors, fit = np.append(np.abs(q[:-1] - q[-1]), np.nan), slice(0, -1)
    out = {"against": against, "h": h.tolist(), "values": q.tolist(),
           "errors": [None if math.isnan(e) else float(e) for e in errors], "order": math.nan, "fit": "",
           "intercept": math.nan}
    round_off = _round_off(errors[fit], q, eps, drift)
    if round_off:
        return {**out, "richardson": math.nan, "extrapolated": math.nan, "note": round_off}
    out.update(richardson(h, q))
    if non_negative and out["extrapolated"] < 0.0:
        out.update(extrapolated=math.nan, note=unresolved_limit(name, out["extrapolated"], q[-1]))
    why = _why_no_fit(h[fit], errors[fit])
    if not why:
        out["order"], out["intercept"] = fit_slope(h[fit], errors[fit])
        out["fit"] = fitted_line(len(h[fit]))
    steps = np.diff(q)
    bent = ("the values are not monotone over the levels, so the coarse ones are not in the asymptotic range"
            if np.any(steps[:-1] * steps[1:] < 0) and "not monotone" not in out["note"] else "")
    apart = disagreement(out["order"], out["richardson"], against)
    return {**out, "note": "; ".join(n for n in (why, out["note"], bent, apart) if n)}


def orders_text(row):
    """A row's two orders in one phrase, as the study's summary prints them: the fitted order and what it is the slope
    of (:func:`fitted_line`), Richardson's estimate, and how far apart they are where that is :data:`DISAGREEMENT`
    or more (the row's note says why)."""
    fitted, estimate = row["order"], row["richardson"]
    text = (f"fitted {fitted:.3f} ({row['fit']})" if math.isfinite(fitted) else "no fitted order") + ", " + (
        f"Richardson {estimate:.3f}" if math.isfinite(estimate) else "no Richardson estimate")
    if math.isfinite(fitted) and math.isfinite(estimate) and abs(fitted - estimate) >= DISAGREEMENT:
        text += f"; they differ by {abs(fitted - estimate):.3f} (the note in index.html says why)"
    return text


def fitted_line(points):
    """What the fitted order is the slope of: :data:`TWO_POINTS`, or the least-squares line through ``points``."""
    return TWO_POINTS if points == 2 else f"the least-squares line through {points} points"


def disagreement(fitted, estimate, against):
    """Why the fitted order and Richardson's estimate differ by :data:`DISAGREEMENT` or more (``""`` when they do
    not, or one is missing): against the finest run, the fit's bias on few levels (the module docstring); against
    the exact value, coarse levels outside the asymptotic range (the fit uses every level, Richardson's the three
    finest)."""
    if not (math.isfinite(fitted) and math.isfinite(estimate)) or abs(fitted - estimate) < DISAGREEMENT:
        return ""
    why = ("against the finest run the fit reads high on few levels (each error carries the finest run's own: first "
           "order reads 1.58 on three levels halving h), so trust Richardson's" if against == "finest run" else
           "the coarse levels, which the fit uses and Richardson's estimate does not, are not in the asymptotic range")
    return (f"the fitted order, {fitted:.2f}, and Richardson's estimate, {estimate:.2f}, differ by "
            f"{abs(fitted - estimate):.2f}: {why}")


def unresolved_limit(name, limit, finest):
    """Why a measure that cannot be negative has no extrapolated limit: Richardson's came out negative."""
    return (f"Richardson's extrapolated limit, {limit:.3g}, is negative, which {name} (>= 0) cannot be: these levels "
            f"do not resolve the limit (the finest value, {finest:.3g}, is smaller than the extrapolation's estimate "
            f"of its error, {finest - limit:.3g})")


def _round_off(errors, q, eps, drift):
    """Why the values are round-off, so that no order can be measured (``""`` when they are not)."""
    level = ROUND_OFF_EPS * eps
    if drift and np.all(np.abs(q) < level):
        return f"conserved to round-off at every level (|value| < {level:.1e}): no order to measure"
    if np.all(np.isfinite(errors)) and errors.size and np.all(errors <= level * np.max(np.abs(q))):
        return f"the levels agree to round-off (errors below {level:.1e} of the value): no order to measure"
    return ""


def _why_no_fit(h, errors):
    """Why the errors give no fitted order (``""`` when they do)."""
    if len(h) < 2:
        return "two errors are needed for a fit: against the finest run, that is three levels"
    if not np.all(np.isfinite(errors)):
        return "a run's value is not finite"
    if np.any(errors == 0.0):
        return "an error is exactly zero: the measure does not change between levels"
    return ""


def richardson(h, q):
    """Richardson's order and extrapolated value from the three finest levels (the module docstring), or ``nan``
    with a note saying why there is none.

    Docs: docs/studying_your_scene.md#observed-orders
    """
    none = {"richardson": math.nan, "extrapolated": math.nan}
    if len(h) < 3:
        return {**none, "note": "Richardson's estimate needs three levels"}
    (h1, h2, h3), (q1, q2, q3) = h[-3:], q[-3:]
    r, r2 = h1 / h2, h2 / h3
    if not math.isclose(r, r2, rel_tol=1e-6):
        return {**none, "note": f"Richardson's estimate needs a constant refinement ratio (here {r:.4g} then {r2:.4g})"}
    d12, d23 = q1 - q2, q2 - q3
    if d12 == 0.0 or d23 == 0.0 or not math.isfinite(d12 / d23):
        return {**none, "note": "Richardson's estimate is undefined: two of the finest levels agree exactly"}
    if d12 * d23 < 0:
        return {**none, "note": "Richardson's estimate is undefined: the three finest levels are not monotone "
                                "(not yet in the asymptotic range)"}
    p = math.log(abs(d12) / abs(d23)) / math.log(r)
    return {"richardson": p, "extrapolated": q3 + (q3 - q2) / (r**p - 1.0) if p != 0.0 else math.nan, "note": ""}


def series_label(row):
    """How a refinement series is named in plots and tables: its fixed keys' values, and what refines with it."""
    with_ = f" (with {', '.join(row['refined_with'])})" if row["refined_with"] else ""
    return (label(row["fixed"]) if row["fixed"] else "all runs") + with_
