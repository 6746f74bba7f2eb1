r"""What a failed conformance case says about the candidate: which rows are compared, where the error is largest
and whether it is one uniform ratio.

* **Compared rows.** Every particle evolves ``x``, ``v`` and its scheme's ``C`` or modes; the deformation fields
  ``F``, ``J`` and ``Jp`` mean something only for the materials that carry them
  (:func:`mpmref.physics.materials.evolved_fields`: ``F`` for solids, ``J`` for the fluid, ``Jp`` for the plastic
  ones). A scene with a solid and the fluid allocates ``F`` and ``J`` for every particle, but a code that leaves
  a fluid's ``F`` alone is right, so those rows are not compared. Grid velocities (``grid_v``, ``grid_v_tilde``)
  are compared on the nodes with mass only: G2P weights node :math:`i`'s velocity by :math:`w_{ip}`, and a node
  without mass has :math:`m_i = \sum_p w_{ip} m_p = 0`, so :math:`w_{ip} = 0` for every particle (each has
  :math:`m_p > 0`) and no particle reads it; a code may leave anything there (the 88-line program leaves
  :math:`\Delta t\,g`).
* **Where.** The row of the worst output with the largest error on its own scale (:func:`worst_row`, the row that
  decides the per-row error of :mod:`~mpmref.conformance.measures`): a particle (its index and position ``x``) or a
  grid node (its index, its multi-index and its position ``origin + i dx``).
* **Uniform ratio.** If the candidate's output is the reference's times one factor :math:`k` everywhere
  (least squares :math:`k = \sum a r / \sum r^2`, and :math:`\max|a - k r|` below a thousandth of the error),
  the case says so: a wrong constant (a factor of :math:`D_p`, a missing :math:`\Delta t`) shows as "× k
  everywhere".
"""

import numpy as np

from ..physics.materials import evolved_fields
from ..state import DEFORMATION_FIELDS
from .measures import row_floor, row_scores

#: output names whose rows are grid nodes
NODE_PREFIXES = ("grid_", "cdf_")
#: the grid velocities, compared on the nodes with mass only (module docstring)
NODE_VELOCITIES = ("grid_v", "grid_v_tilde")


def compared_rows(scene, inputs):
    """``{output: boolean mask over rows}``: for ``F``, ``J``, ``Jp`` the particles whose material evolves that field;
    for the grid velocities of a stage given the node masses (``grid_update``), the nodes with mass."""
    rows = {}
    if "grid_mass" in inputs:
        rows.update(dict.fromkeys(NODE_VELOCITIES, np.asarray(inputs["grid_mass"]) > 0))
    if "material" not in inputs:
        return rows
    material = np.asarray(inputs["material"])
    for name in DEFORMATION_FIELDS:  # the fields only some materials carry (module docstring)
        ids = [i for i, m in enumerate(scene.material_list) if name in evolved_fields(m)]
        rows[name] = np.isin(material, ids)
    return rows


def restrict(name, array, rows):
    """``array`` on the compared rows of output ``name`` (all of it unless ``rows`` has a mask for it of its length)."""
    mask = rows.get(name)
    array = np.asarray(array)
    if mask is None or array.ndim == 0 or array.shape[0] != mask.shape[0]:
        return array
    return array[mask]


def _row_numbers(name, rows, length):
    mask = rows.get(name)
    return np.flatnonzero(mask) if mask is not None and mask.shape[0] == length else np.arange(length)


def worst_row(name, got, expected, rows):
    """The row (particle or node, by its index in the inputs) of output ``name`` furthest from the reference on its own
    scale (:func:`.measures.row_scores`: the row that decides the per-row error), or by absolute difference where the
    reference is all zero; ``None`` if nothing can be compared."""
    a = np.asarray(got, dtype=np.float64)
    r = np.asarray(expected, dtype=np.float64)
    if a.shape != r.shape or a.ndim == 0 or a.size == 0:
        return None
    numbers = _row_numbers(name, rows, r.shape[0])
    a, r = restrict(name, a, rows), restrict(name, r, rows)
    if not a.size:
        return None
    scores = row_scores(a, r, row_floor(got, expected), 1)
    if scores is None:
        scores = np.nan_to_num(np.abs(a - r), nan=np.inf).reshape(len(numbers), -1).max(axis=1)
    return int(numbers[np.argmax(scores)])


def worst_place(name, got, expected, rows, scene, inputs):
    """Where output ``name`` differs most from the reference: ``"particle 17 at x = [...]"``, ``"node 40 (i = (4,
    4)) at x = [...]"``, or ``"row 3"`` (:func:`worst_row`); ``""`` if nothing can be compared."""
    row = worst_row(name, got, expected, rows)
    if row is None:
        return ""
    length, grid = np.shape(expected)[0], scene.grid
    if name.startswith(NODE_PREFIXES) and length == grid.n_nodes:
        index = np.unravel_index(row, grid.node_shape)
        position = grid.origin + np.array(index) * grid.dx
        return f"node {row} (i = {tuple(int(i) for i in index)}) at x = {_vector(position)}"
    if "x" in inputs and length == len(inputs["x"]):
        return f"particle {row} at x = {_vector(inputs['x'][row])}"
    return f"row {row}"


def uniform_ratio(name, got, expected, rows):
    """The factor :math:`k` with ``got`` = k × ``expected`` on every compared entry of output ``name`` (to a
    thousandth of the error), or ``None`` when the error is not one ratio (or the output is one number, which any
    ratio fits, or the ratio is 1 to within 1e-6, which says nothing)."""
    a = restrict(name, np.asarray(got, dtype=np.float64), rows).ravel()
    r = restrict(name, np.asarray(expected, dtype=np.float64), rows).ravel()
    if a.shape != r.shape or a.size < 2 or not np.all(np.isfinite(a)):
        return None
    norm = float(r @ r)
    if norm == 0.0:
        return None
    k = float(a @ r) / norm
    scale = np.max(np.abs(r))
    error = np.max(np.abs(a - r)) / scale
    residual = np.max(np.abs(a - k * r)) / scale
    return k if error > 0.0 and residual <= 1e-3 * error and abs(k - 1.0) > 1e-6 else None


def _vector(x):
    return "[" + ", ".join(f"{v:.6g}" for v in np.asarray(x, dtype=np.float64)) + "]"
