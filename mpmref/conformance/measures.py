r"""How far a candidate's output is from the reference's: case-wide, and row by row on each particle's own scale.

* **Case-wide** (:func:`relative_error`): :math:`\max|a - r| / \max|r|` over every entry of an output; a ledger term
  relative to the energy scale of its state (:func:`output_scale`).
* **Per row** (:func:`row_relative_error`): each particle's (or node's) error over its own largest entry, with a floor
  of :data:`ROW_FLOOR` times the output's largest entry, so that a particle near rest, whose own stress is small,
  cannot be wrong by a large part of it and pass beside a large one.

An output's error as judged is the larger of the two (:class:`OutputError`, :func:`judged_error`); a case passes when
that is at most its tolerance for every output (docs/conformance.md, "The error").
"""

import math

import numpy as np

from .case import DEFAULT_RTOL


def relative_error(candidate, reference, scale=None):
    r"""Relative error of one output array: :math:`\max|a - r| / \max|r|`, or :math:`\max|a - r| / S` with a given
    ``scale`` :math:`S`.

    The maxima run over every entry of the array. Where the reference is all zero (and no scale is given) the
    denominator is 1, so the error is :math:`\max|a|`. A shape mismatch or a non-finite difference counts as
    ``inf``.
    """
    a, r = np.asarray(candidate), np.asarray(reference)
    if a.shape != r.shape:
        return math.inf
    diff = float(np.max(np.abs(a.astype(np.float64) - r.astype(np.float64)), initial=0.0))
    if scale is None:
        scale = float(np.max(np.abs(r.astype(np.float64)), initial=0.0))
    error = diff / scale if scale > 0.0 else diff
    return error if math.isfinite(error) else math.inf


#: the floor of a row's own scale, as a fraction of the output's largest entry, per dtype (:func:`row_relative_error`).
#: In float64, :data:`ROW_FLOOR_ULPS` ulps of the case's scale (the round-off a correct code may leave anywhere,
#: 2.3e-13 of it) make an error of the tolerance there: the floor is 0.23 of the scale. In float32 the tolerance is
#: itself 420 ulps, and the float32 reference lies up to 3.6e-6 from the float64 one: no floor below the case's scale
#: leaves room for a correct code, and the per-row error is the case-wide one (a floor of 1)
ROW_FLOOR_ULPS = 1024
ROW_FLOOR = {"float64": ROW_FLOOR_ULPS * float(np.finfo(np.float64).eps) / DEFAULT_RTOL["float64"], "float32": 1.0}
#: outputs whose rows are the first two axes (a class or kick row, then a node)
TWO_AXIS_ROWS = ("class_sums", "kicks")


def row_relative_error(candidate, reference, floor, leading=1, natural=0.0):
    r"""Per-row relative error of one output: each particle's (or node's) error on its own scale, with a floor.

    .. math:: e_{row} = \max_p \frac{\max_k |a_{pk} - r_{pk}|}{\max\left(\max_k |r_{pk}|,\ \phi\,S\right)},
              \qquad S = \max_{p,k} |r_{pk}|,

    with :math:`p` the rows (the first ``leading`` axes: a particle, a node, a class and a node), :math:`k` the entries
    of a row (a particle's :math:`\tau_p`, a node's momentum) and :math:`\phi` = ``floor``. A particle whose own
    stress is small is judged on it, so that its error cannot hide behind a large one elsewhere; the floor
    :math:`\phi S` is where theory puts the row at zero (a particle at rest, an empty node) and a correct code's
    round-off of the case's scale is all there is. An output whose entries are sums of larger terms has its round-off
    on the scale of those terms: ``natural``, where given and larger, stands for :math:`S` in the floor
    (:func:`natural_scales`). Since the denominator is at most :math:`S` otherwise, :math:`e_{row}` is at least the
    case-wide :func:`relative_error`. Where the reference is all zero, the case-wide rule (the absolute
    error); a shape mismatch or a non-finite value: ``inf``.
    """
    a, r = np.asarray(candidate, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    if a.shape != r.shape:
        return math.inf
    scores = row_scores(a, r, floor, leading, natural)
    if scores is None:
        return relative_error(a, r)
    error = float(np.max(scores, initial=0.0))
    return error if math.isfinite(error) else math.inf


def row_scores(candidate, reference, floor, leading=1, natural=0.0):
    """Each row's error on its own scale (the terms of :func:`row_relative_error`; NaN counts as ``inf``), or ``None``
    where there are no rows or the reference is all zero."""
    a, r = np.asarray(candidate, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    scale = float(np.max(np.abs(r), initial=0.0))
    if a.ndim < leading or a.size == 0 or scale == 0.0:
        return None
    rows = int(np.prod(a.shape[:leading]))
    diff = np.nan_to_num(np.abs(a - r), nan=np.inf).reshape(rows, -1).max(axis=1, initial=0.0)
    own = np.abs(r).reshape(rows, -1).max(axis=1, initial=0.0)
    return diff / np.maximum(own, floor * max(scale, natural))


def row_floor(*arrays):
    """The floor :data:`ROW_FLOOR` of the coarsest dtype of ``arrays`` (float64's for any other)."""
    return max(ROW_FLOOR.get(np.asarray(a).dtype.name, ROW_FLOOR["float64"]) for a in arrays)


def leading_axes(name):
    """How many leading axes index the rows of output ``name``: two for :data:`TWO_AXIS_ROWS`, else one."""
    return 2 if name in TWO_AXIS_ROWS else 1


class OutputError(float):
    """An output's error as judged, the larger of its per-row error (:func:`row_relative_error`) and its case-wide one
    (:func:`relative_error`): a float, with the case-wide figure as ``case_wide``."""

    def __new__(cls, judged, case_wide):
        error = super().__new__(cls, max(judged, case_wide))
        error.case_wide = case_wide
        return error

    def __reduce__(self):
        return OutputError, (float(self), self.case_wide)


def natural_scales(expected, dx, wave_speed=0.0, dt=0.0):
    r"""``{output: scale}``: the scale of an output's round-off where it can exceed the output's own largest entry, the
    base of its per-row floor (:func:`row_relative_error`).

    * ``v``: a step kicks each velocity by :math:`\Delta t\, f_i/m_i`, made of the stress, whose round-off is of the
      stiffness; in velocity that is :math:`c\,(c\,\Delta t/\Delta x)`, the rest wave speed :math:`c` times the
      step's elastic CFL number, whatever the particle's own speed (a block at rest under gravity moves by little
      more than that);
    * ``C``: :math:`C_p = D_p^{-1}\sum_i w_{ip} v_i (x_i - x_p)^T` sums terms of a speed over a cell; in a block moving
      as one they cancel to near zero, and their round-off is of :math:`\max(|v|, c^2\Delta t/\Delta x)/\Delta x`.
    """
    kick = wave_speed * wave_speed * dt / dx
    out = {"v": kick} if "v" in expected and kick > 0 else {}
    if "C" in expected and "v" in expected:
        speed = float(np.max(np.abs(np.asarray(expected["v"], dtype=np.float64)), initial=0.0))
        out["C"] = max(speed, kick) / dx
    return out


def judged_error(name, value, ref, expected, natural=0.0, settled=False):
    r"""The :class:`OutputError` of output ``name``: the case-wide error (relative to the reference's energy scale for a
    ledger term, :func:`output_scale`) and, for an output with rows, the per-row error with the floor of its dtype
    (:data:`ROW_FLOOR`, of the coarser dtype of the two) on the larger of its largest entry and ``natural``
    (:func:`natural_scales`).

    ``settled``: the output of many steps from rest (``from-rest``), whose velocities and their gradients may stay below
    the round-off its stress leaves in them every step (a jelly block settling under gravity: :math:`C` of order
    :math:`g/c`, the stress's round-off :math:`\epsilon c^2\Delta t/\Delta x^2`); its case-wide error is then taken
    over the larger of its largest entry and the floor of ``natural``, as its rows' are."""
    scale = output_scale(name, expected)
    if settled and natural > 0.0 and scale is None:
        floor = row_floor(value, ref) * natural
        scale = max(float(np.max(np.abs(np.asarray(ref, dtype=np.float64)), initial=0.0)), floor)
    case_wide = relative_error(value, ref, scale)
    if output_scale(name, expected) is not None or np.ndim(ref) == 0:
        return OutputError(case_wide, case_wide)
    return OutputError(row_relative_error(value, ref, row_floor(value, ref), leading_axes(name), natural), case_wide)


def output_scale(name, expected):
    """The denominator of output ``name``'s error other than its own largest entry, or ``None``: the reference's
    ``energy_scale`` for a ledger term (``ledger_*``). A term is a difference of energies of that size, so its
    round-off is relative to it, not to the term (which theory may put at zero:
    :func:`mpmref.observe.ledger.energy_scale`)."""
    return float(expected["energy_scale"]) if name.startswith("ledger_") and "energy_scale" in expected else None
