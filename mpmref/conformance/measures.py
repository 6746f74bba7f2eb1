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
    round-off of the case's scale is all there is. An output whose entries are sums of larger terms, or made of a
    stiffness, has its round-off on the scale of those: ``natural`` (one number, or one per row), where larger,
    stands for :math:`S` in the floor (:func:`natural_scales`). Since the denominator is at most :math:`S` otherwise,
    :math:`e_{row}` is at least the case-wide :func:`relative_error`. Where the reference is all zero and there is no
    natural scale, the case-wide rule (the absolute error); a shape mismatch or a non-finite value: ``inf``.
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
    where there are no rows, or the reference is all zero and there is no natural scale."""
    a, r = np.asarray(candidate, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    base = np.maximum(float(np.max(np.abs(r), initial=0.0)), natural)
    if a.ndim < leading or a.size == 0 or not np.any(base > 0.0):
        return None
    rows = int(np.prod(a.shape[:leading]))
    diff = np.nan_to_num(np.abs(a - r), nan=np.inf).reshape(rows, -1).max(axis=1, initial=0.0)
    own = np.abs(r).reshape(rows, -1).max(axis=1, initial=0.0)
    return diff / np.maximum(own, floor * base)


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


def natural_scales(expected, inputs, dx, stiffness=None, wave_speed=0.0, dt=0.0, mode_degree=0):
    r"""``{output: scale}``: the scale of an output's round-off where it can exceed the output's own largest entry, the
    base of its floor (:func:`row_relative_error`, :func:`judged_error`). Where theory puts a whole output at zero (a
    particle at rest, a velocity that cancels), both codes leave round-off of these scales, and only they tell a wrong
    value from round-off.

    * ``tau`` (per particle): :math:`\tau_p = P_p F_p^T` is made of the stress at the particle's stiffness
      :math:`k_p = \rho_p c_p^2` (``stiffness``) and of its SVD, whose round-off is
      :math:`\epsilon\,k_p \max(1, \|F_p\|_F^2/d)`, whatever :math:`\tau_p` is (zero for :math:`F_p` a rotation);
    * ``grid_force``: :math:`f_i = -\sum_p V_p^0 \tau_p \nabla w_{ip}` carries each term's round-off,
      :math:`\max_p V_p^0 k_p \max(1, \|F_p\|_F^2/d) / \Delta x`; the fused P2G's ``grid_momentum_after_force`` that
      times :math:`\Delta t`;
    * ``grid_momentum``: :math:`\sum_p w_{ip} m_p (v_p + C_p (x_i - x_p))`, whose terms are of
      :math:`\max_p m_p (|v_p| + 2\Delta x |C_p|)`;
    * ``v``: G2P sums grid velocities, FLIP adds the particle's own, and a step kicks each velocity by
      :math:`\Delta t\, f_i/m_i`, made of the stress, whose round-off in velocity is :math:`c\,(c\,\Delta t/\Delta x)`,
      the wave speed :math:`c` times the step's elastic CFL number: the largest of the input speeds and that kick;
    * ``x``: :math:`x_p + \Delta t\, v_p`, with the round-off of ``v`` times :math:`\Delta t`;
    * ``F`` and ``J``: :math:`(I + \Delta t\, \nabla v_p) F_p`, whose velocity gradient sums the grid velocities over a
      cell: :math:`\max(1, \Delta t\, v/\Delta x)` times the largest input entry, with :math:`v` the scale of ``v``;
    * ``C``: :math:`C_p = D_p^{-1}\sum_i w_{ip} v_i (x_i - x_p)^T` sums terms of a speed over a cell; in a block moving
      as one they cancel to near zero, and their round-off is of :math:`\max(|v|, c^2\Delta t/\Delta x)/\Delta x`;
    * ``modes`` (PolyPIC): :math:`c_{pr} = \sum_i w_{ip} v_i N_r(x_i - x_p) / \sum_i w_{ip} N_r^2` carries the
      round-off of its speeds over the scale of its basis function, :math:`\Delta x^{k}` for a mode of degree
      :math:`k`: the scale of ``v`` over :math:`\Delta x` to the highest degree (``mode_degree``), which decides a
      particle's row;
    * ``wave_speed`` (per particle, the return map's): :math:`c_p` reads :math:`J_p = \det F_p`, whose round-off is
      :math:`\epsilon\,(\|F_p\|_F^2/d)^{d/2}`, not :math:`\epsilon\,|\det F_p|`: near a vanishing singular value
      (the extremes) that is the condition :math:`\kappa_p = \max(1, (\|F_p\|_F^2/d)^{d/2} / |\det F_p|)` times
      more, and :math:`c_p` moves by about :math:`\epsilon\kappa_p` of itself: :math:`\kappa_p c_p`, of the output
      ``F``.

    Parameters
    ----------
    expected : dict
        The reference's outputs (which outputs there are; the output speeds).
    inputs : dict
        The case's inputs (particle ``v``, ``C``, ``F``, ``mass``, ``vol0``; ``grid_v``, ``grid_v_tilde``).
    dx : float
        Cell size :math:`\Delta x`.
    stiffness : ndarray or None
        :math:`k_p = \rho_p c_p^2` of each input particle, :math:`c_p` the larger of its material's wave speed at rest
        and in its state.
    wave_speed : float
        The largest wave speed :math:`c` of the materials, at rest or in the particles' states.
    dt : float
        The stage's :math:`\Delta t` (0 for a stage without one).
    mode_degree : int
        The highest degree of a PolyPIC mode, :math:`d\,(K - 1)` for a kernel of support :math:`K` (0 without modes).
    """
    speed_in = max(_largest(inputs.get(k)) for k in ("v", "grid_v", "grid_v_tilde"))
    kick = wave_speed * wave_speed * dt / dx
    out = {"v": max(kick, speed_in)}
    out["x"] = dt * out["v"]
    gradient = dt * out["v"] / dx
    out.update({k: max(1.0, gradient) * _largest(inputs[k]) for k in ("F", "J") if k in inputs})
    if "v" in expected:
        out["C"] = max(_largest(expected["v"]), speed_in, kick) / dx
    out["modes"] = out["v"] / dx**mode_degree
    if "mass" in inputs and "v" in inputs:
        affine = 2.0 * dx * _row_largest(inputs["C"]) if "C" in inputs else 0.0
        out["grid_momentum"] = _largest(inputs["mass"] * (_row_largest(inputs["v"]) + affine))
    if stiffness is not None:
        tau = stress_scales(inputs, stiffness)
        force = _largest(np.asarray(inputs["vol0"], dtype=np.float64) * tau) / dx
        out.update({"tau": tau, "grid_force": force, "grid_momentum_after_force": dt * force})
    if "wave_speed" in expected and "F" in expected:
        out["wave_speed"] = np.abs(np.asarray(expected["wave_speed"], dtype=np.float64)) * determinant_condition(
            expected["F"])
    return {k: v for k, v in out.items() if k in expected and np.any(np.asarray(v) > 0.0)}


def determinant_condition(F):
    r""":math:`\kappa_p = \max(1, (\|F_p\|_F^2/d)^{d/2} / |\det F_p|)` of each particle (float64 (n,)): how many
    times its determinant's round-off exceeds :math:`\epsilon |\det F_p|` (:func:`natural_scales`, ``wave_speed``);
    1 for a rotation, at most :math:`1/\epsilon` (a singular :math:`F_p`, whose determinant is round-off alone)."""
    F = np.asarray(F, dtype=np.float64)
    d = F.shape[-1]
    mean_square = np.einsum("pij,pij->p", F, F) / d
    with np.errstate(divide="ignore"):
        kappa = mean_square ** (d / 2) / np.abs(np.linalg.det(F))
    return np.clip(np.nan_to_num(kappa, nan=np.inf), 1.0, 1.0 / np.finfo(np.float64).eps)


def stress_scales(inputs, stiffness):
    r""":math:`k_p \max(1, \|F_p\|_F^2 / d)` of each particle (float64 (n,)): the round-off scale of its Kirchhoff
    stress, with :math:`k_p` its ``stiffness`` and :math:`\|F_p\|_F^2/d` the mean square of its deformation gradient's
    singular values (1 for a particle without one)."""
    k = np.asarray(stiffness, dtype=np.float64)
    if "F" not in inputs:
        return k
    F = np.asarray(inputs["F"], dtype=np.float64)
    return k * np.maximum(1.0, np.einsum("pij,pij->p", F, F) / F.shape[-1])


def _largest(array):
    """max |entry| of ``array`` as a float (0 for None or empty)."""
    return 0.0 if array is None else float(np.max(np.abs(np.asarray(array, dtype=np.float64)), initial=0.0))


def _row_largest(array):
    """max |entry| of each row (first axis) of ``array``, float64."""
    a = np.abs(np.asarray(array, dtype=np.float64))
    return a.reshape(len(a), -1).max(axis=1, initial=0.0)


def judged_error(name, value, ref, expected, natural=0.0):
    r"""The :class:`OutputError` of output ``name``: the case-wide error and, for an output with rows, the per-row error
    with the floor of its dtype (:data:`ROW_FLOOR`, of the coarser dtype of the two) on the larger of its largest entry
    and ``natural`` (:func:`natural_scales`, a number or one per row).

    The case-wide error is relative to the reference's energy scale for a ledger term (:func:`output_scale`), else to
    the larger of the output's largest entry and the floor of ``natural``: where theory puts the whole output at zero
    (one particle at rest, a jelly block settling under gravity, whose :math:`C` of order :math:`g/c` stays below the
    round-off :math:`\epsilon c^2\Delta t/\Delta x^2` its stress leaves in it every step), the round-off of the
    natural scale is all either code computes."""
    scale = output_scale(name, expected)
    largest = float(np.max(natural, initial=0.0))
    if scale is None and largest > 0.0:
        scale = max(_largest(ref), row_floor(value, ref) * largest)
    case_wide = relative_error(value, ref, scale)
    if output_scale(name, expected) is not None or np.ndim(ref) == 0:
        return OutputError(case_wide, case_wide)
    return OutputError(row_relative_error(value, ref, row_floor(value, ref), leading_axes(name), natural), case_wide)


def output_scale(name, expected):
    """The denominator of output ``name``'s error other than its own largest entry, or ``None``: for a ledger term
    (``ledger_*``), the larger of the reference's ``energy_scale`` and its largest term. A term is a difference of
    energies of that size, so its round-off is relative to them, not to the term (which theory may put at zero:
    :func:`mpmref.observe.ledger.energy_scale`); and energies that differ by a term are at least half its size, so
    the largest term bounds them from below where the step leaves the energies of its input far behind (a fluid
    collapsed far beyond the Δt its rest wave speed allows, whose energy grows a millionfold in the step)."""
    if not name.startswith("ledger_") or "energy_scale" not in expected:
        return None
    terms = [abs(float(v)) for k, v in expected.items() if k.startswith("ledger_")]
    return max(float(expected["energy_scale"]), *terms)
