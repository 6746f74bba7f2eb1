r"""Extreme states by design: the deterministic states where the bugs of real MPM codes live.

The drawn states of :mod:`.states` lie where correct codes agree and most wrong ones disagree: ``F`` a random rotation
times a stretch of 1e-3 to 0.2, positions well inside cells, ``J`` near 1. The bugs that survive into shipped codes
live elsewhere (docs/conformance.md, "Extremes"): an SVD that takes the diagonal of the symmetric polar factor
:math:`S = R^T F` as the singular values where :math:`|S_{01}|` is small (every particle at rest has :math:`F = I`),
a base node that changes where a particle sits exactly on a face, a return map that decides "on the yield surface" with
a tolerance. Each :class:`Extreme` is one family of such states; a case that holds it (:attr:`ConformanceCase.extreme
<mpmref.conformance.case.ConformanceCase.extreme>`) draws its state as every case does, then puts every other particle
(:func:`extreme_rows`) at one rung of the family's ladder, so that the drawn half sets the case's scale and each
particle at an extreme is judged on its own (:func:`mpmref.conformance.measures.row_relative_error`). Each such particle
has a note, ``"|S₀₁| = 1e-07"``, that a failure names.

The families (``name``: what it holds, the stages it concerns):

* ``rest`` (stress): :math:`F = I`, a rotation, a diagonal :math:`F`, two or three equal singular values, singular
  values equal to 1e-6, 1e-9 and 1e-12 (:func:`rest_gradients`); the fluid at :math:`J = 1` and
  :math:`J = 1 \pm 10^{-3}, \dots, 10^{-12}` (:func:`rest_volumes`).
* ``near-symmetric-F`` (stress, solids): :math:`F = R(I + bM)`, so that the symmetric polar factor has
  :math:`|S_{01}| = b` for :math:`b = 10^{-3}, \dots, 10^{-12}` (:func:`near_symmetric_gradients`).
* ``collapse`` (stress, return map): one singular value :math:`10^{-2}, \dots, 10^{-8}` (:math:`J \to 0^+`), and an
  inverted :math:`F` (last signed singular value :math:`-0.5, -10^{-3}, -10^{-6}`) where the material's stress is
  finite there (:func:`collapse_gradients`; the Neo-Hookean solid's :math:`\ln J` is not, so it is refused); the fluid
  at :math:`J = 10^{-1}, \dots, 10^{-4}` (its :math:`J < 0` means nothing and is not drawn).
* ``yield-surface`` (return map): snow with singular values exactly on :math:`1 - \theta_c` and :math:`1 + \theta_s`,
  just past them and just inside by :math:`10^{-12}, 10^{-9}, 10^{-7}`, and :math:`J_P` at its clamp; sand on the
  Drucker–Prager cone (:math:`\delta\gamma = 0`), just past and inside it, at the apex and in tension
  (:func:`snow_yield_states`, :func:`sand_yield_states`).
* ``on-nodes-and-faces`` (P2G, G2P, steps): particles exactly on a node, on a face (one coordinate on a node line) and
  where the kernel's base node switches (:func:`on_grid_lines`), each whose stencil nodes all hold mass from the drawn
  particles (a linear kernel's gradient reads the node of zero weight beyond it).
* ``domain-edge`` (P2G, G2P, steps): particles at the lowest and highest positions the kernel allows on each axis, in
  the walls' band, moving out (:func:`at_domain_edge`).
* ``massless-neighbours`` (grid update): nodes with mass beside nodes without, and nearly empty ones
  (:func:`massless_neighbours`).
* ``cfl-limit`` (steps and their ledgers): Δt at the scheme's measured stability limit
  (:func:`mpmref.run.stability.stable_cfl`).
* ``from-rest`` (steps): :math:`F = I`, :math:`v = 0`, a block of particles on the floor under gravity, or pushed,
  run for :data:`FROM_REST_STEPS` steps, which reach the near-rest states of every real run by themselves
  (:func:`at_rest_block`).
* ``large-stiffness`` (stress, steps): the materials a million times stiffer, where float32's range is tested.

A particle at a position extreme is placed so that its grid coordinate :math:`(x - o)/\Delta x`, computed as the
reference computes it in the case's dtype, is exactly on the line (:func:`exactly_at`).
"""

from dataclasses import dataclass, field

import numpy as np

from ..physics.kernels import stencil_offsets
from ..physics.plasticity import DruckerPragerSand, SnowPlasticity
from .states import random_rotations

#: the rungs of the near-symmetric ladder: :math:`|S_{01}| = 10^{-3}, \dots, 10^{-12}`
NEAR_SYMMETRIC = tuple(10.0**-k for k in range(3, 13))
#: the symmetric direction of the near-symmetric states (:math:`S = I + bM`): off-diagonal 1, a diagonal of the same
#: order, so that the particle is near rest and its stress of order :math:`b`
NEAR_SYMMETRIC_M = np.array([[0.5, 1.0, 0.0], [1.0, -0.3, 0.0], [0.0, 0.0, 0.2]])
#: gaps of the nearly equal singular values, :math:`\sigma_2 = \sigma_1 (1 - g)`
NEAR_EQUAL_GAPS = (1e-6, 1e-9, 1e-12)
#: the smallest singular value of a collapsing solid (:math:`J \to 0^+`)
COLLAPSE_SIGMAS = (1e-2, 1e-4, 1e-6, 1e-8)
#: the last signed singular value of an inverted :math:`F` (kept away from :math:`\sigma_i + \sigma_j = 0`, a scaled
#: reflection, where the polar rotation is not unique)
INVERTED_SIGMAS = (-0.5, -1e-3, -1e-6)
#: the fluid's volume ratios near rest, :math:`J = 1 \pm \epsilon`, and collapsing
REST_VOLUME_OFFSETS = (1e-3, 1e-6, 1e-9, 1e-12)
COLLAPSE_VOLUMES = (1e-1, 1e-2, 1e-3, 1e-4)
#: how far past (or inside) a yield surface the yield-surface states lie, relative
YIELD_OFFSETS = (1e-10, 1e-9, 1e-7)
#: steps of a ``from-rest`` case, per dimension: at :data:`REST_CFL` a wave crosses the block's height
#: (:data:`BLOCK_CELLS`) in 10 steps in 2D and 5 in 3D, so that the waves the block starts cross it twice
FROM_REST_STEPS = {2: 20, 3: 10}
#: the cells per axis of a ``from-rest`` block (two particles per cell and axis: 64 in 2D, 128 in 3D); gravity is along
#: axis 1, its height
BLOCK_CELLS = {2: (4, 4), 3: (4, 2, 2)}
#: the push of a ``pushed-from-rest`` block, as a fraction of the rest wave speed (:func:`at_rest_block`)
PUSH = 1e-2
#: the stiffness factor of the ``large-stiffness`` cases
STIFFNESS_FACTOR = 1.0e6


@dataclass(frozen=True)
class Extreme:
    """One family of extreme states.

    Attributes
    ----------
    name : str       the family, in the case's name (``stress-2d-fixed_corotated-near-symmetric-F``)
    holds : str      what its cases hold, in words, for the report
    state : callable ``state(scene, flat, rng, dtype) -> (flat, notes)``: the drawn state ``flat`` with the rows of
                     :func:`extreme_rows` at the extreme, and one note per row (``None`` for a drawn row); ``None``: the
                     drawn state (the extreme is in the case's scene or Δt)
    grid : bool      whether ``state`` changes a grid state (``grid_update``) rather than particles
    multi_step : bool  a ``step`` case runs :data:`FROM_REST_STEPS` steps (``from-rest``), else one
    cfl : str        ``"limit"``: Δt at the scheme's stability limit; ``"rest"``: the CFL number
                     :data:`REST_CFL`; ``None``: drawn
    exact_grid : bool  the case's cell size a power of two and its origin a whole number of cells, so that node and
                     face positions are exact in any arithmetic
    float32 : bool   whether float32 cases hold it: not the positions, Δt at the limit or many steps, where the float32
                     reference itself lies further from the float64 one than the float32 tolerance (measured: 0.25 of
                     ``F`` for a linear kernel's particle at the domain's edge, 8e-5 of ``C`` after 80 steps)
    """

    name: str
    holds: str
    state: object = field(default=None, repr=False)
    grid: bool = False
    multi_step: bool = False
    cfl: str | None = None
    exact_grid: bool = False
    float32: bool = True


#: the CFL number of a ``from-rest`` case (a run's usual step, not a drawn one: at rest nothing moves otherwise)
REST_CFL = 0.4


def extreme_rows(n):
    """The rows put at the extreme: every other one (0, 2, 4, ...)."""
    return np.arange(0, n, 2)


# ------------------------------------------------------------------------------------------ deformation
def _rotation(rng, dim):
    return random_rotations(rng, 1, dim)[0]


def _spectral(rng, sigma):
    r""":math:`U\,\mathrm{diag}(\sigma)\,V^T` with random rotations :math:`U, V`."""
    dim = len(sigma)
    return (_rotation(rng, dim) * np.asarray(sigma, dtype=float)) @ _rotation(rng, dim).T


def rest_gradients(rng, dim):
    r"""``[(F, note)]``: :math:`F = I`; a rotation; a diagonal stretch; a scaled rotation (every singular value equal);
    in 3D two equal singular values; and :math:`\sigma_2 = \sigma_1(1 - g)` for each gap of
    :data:`NEAR_EQUAL_GAPS`."""
    eye = np.eye(dim)
    out = [(eye, "F = I"), (_rotation(rng, dim), "F a rotation"),
           (np.diag([1.1, 0.95, 1.02][:dim]), "F diagonal"), (0.97 * _rotation(rng, dim), "all singular values 0.97")]
    if dim == 3:
        out.append((_spectral(rng, [1.05, 0.98, 0.98]), "σ₂ = σ₃"))
    out += [(_spectral(rng, [1.05, 1.05 * (1.0 - g), 0.98][:dim]), f"σ₂ = σ₁ (1 - {g:.0e})") for g in NEAR_EQUAL_GAPS]
    return out


def near_symmetric_gradients(rng, dim):
    r"""``[(F, note)]``: :math:`F = R\,(I + bM)` for each :math:`b` of :data:`NEAR_SYMMETRIC`, :math:`R` a random
    rotation and :math:`M` = :data:`NEAR_SYMMETRIC_M`: the symmetric polar factor is :math:`S = I + bM`, with
    :math:`|S_{01}| = b` (the states where an SVD that takes :math:`\operatorname{diag} S` as the singular values below
    a threshold is wrong: :math:`\prod_i S_{ii} = \det F + b^2` in 2D)."""
    M = NEAR_SYMMETRIC_M[:dim, :dim]
    return [(_rotation(rng, dim) @ (np.eye(dim) + b * M), f"|S₀₁| = {b:.0e}") for b in NEAR_SYMMETRIC]


def collapse_gradients(rng, dim):
    r"""``[(F, note)]``: one singular value of :data:`COLLAPSE_SIGMAS` (:math:`J \to 0^+`), then the inverted
    :math:`F` of :data:`INVERTED_SIGMAS` (the last signed singular value)."""
    rest = [1.0] * (dim - 1)
    out = [(_spectral(rng, rest + [s]), f"J = {s:.0e}") for s in COLLAPSE_SIGMAS]
    return out + [(_spectral(rng, rest + [s]), f"inverted, σ_d = {s:g}") for s in INVERTED_SIGMAS]


def rest_volumes():
    r"""``[(J, note)]``: :math:`J = 1` and :math:`J = 1 \pm \epsilon` for :data:`REST_VOLUME_OFFSETS`."""
    return [(1.0, "J = 1")] + [(1.0 + s * e, f"J = 1 {'+-'[s < 0]} {e:.0e}") for e in REST_VOLUME_OFFSETS
                               for s in (1.0, -1.0)]


def collapse_volumes():
    """``[(J, note)]``: :data:`COLLAPSE_VOLUMES`."""
    return [(j, f"J = {j:.0e}") for j in COLLAPSE_VOLUMES]


def _assign(flat, rows, key, ladder, notes):
    """Put the rows ``rows`` at the rungs of ``ladder`` (``[(value, note)]``), cycling; note each."""
    for k, p in enumerate(rows):
        value, note = ladder[k % len(ladder)]
        flat[key][p] = value
        notes[p] = note


def deformation_state(gradients, volumes):
    """A ``state`` function (:class:`Extreme`) that puts the extreme rows of solids at the rungs of ``gradients(rng,
    dim)`` and those of the fluid at ``volumes()`` (either may be ``None``: those rows stay drawn). A rung where the
    reference's stress is not finite (the Neo-Hookean solid's inverted :math:`F`) or not well-conditioned
    (:func:`well_conditioned`) is left out for that material."""
    def state(scene, flat, rng, dtype):
        """The drawn ``flat`` with its extreme rows at the family's rungs (those finite and well-conditioned for each
        material, :func:`_finite_rungs`), and their notes."""
        n = len(flat["x"])
        notes = [None] * n
        rows = extreme_rows(n)
        material = flat["material"]
        ladder = gradients(rng, scene.dim) if gradients else []
        for index, m in enumerate(scene.material_list):
            mine = rows[material[rows] == index]
            if m.tracks == "F" and ladder:
                _assign(flat, mine, "F", _finite_rungs(m, ladder, flat, mine), notes)
            elif m.tracks == "J" and volumes:
                _assign(flat, mine, "J", volumes(), notes)
        return flat, notes

    return state


def _finite_rungs(material, ladder, flat, rows):
    """The rungs of ``ladder`` at which ``material``'s Kirchhoff stress (with the first row's ``Jp``) is finite and
    well-conditioned (:func:`well_conditioned`)."""
    F = np.array([f for f, _ in ladder])
    Jp = np.full(len(F), flat["Jp"][rows[0]] if material.plastic and len(rows) else 1.0)

    def stress(G):
        with np.errstate(all="ignore"):
            return material.kirchhoff_stress(*((G, Jp) if material.plastic else (G,)))

    keep = well_conditioned(stress, F, stress(np.broadcast_to(1.1 * np.eye(F.shape[1]), F.shape)))
    return [rung for rung, ok in zip(ladder, keep) if ok]


#: a relative change of every entry of ``F`` by this much ...
CONDITION_PROBE = 1e-15
#: ... may move a rung's stress by at most this much of its scale, else the rung is left out: no code could be checked
#: at 1e-12 there. A third of the bound every case meets under a random change of 1e-15 (tests/test_conformance.py):
#: two sign patterns find the direction of a rung's largest sensitivity only to within that
CONDITION_BOUND = 3e-14


def well_conditioned(stress, F, floor_stress):
    r"""Whether each rung ``F`` (m, d, d) gives a finite stress that a relative change of :data:`CONDITION_PROBE` in
    each entry (two fixed sign patterns) moves by at most :data:`CONDITION_BOUND` of its scale: the larger of its own
    largest entry and that of ``floor_stress`` (the stress of a 10 % stretch, of the drawn states' scale, where a
    rung's own stress is zero).

    Where a material's stress reads :math:`J` or :math:`\sigma_d` through a logarithm (Neo-Hookean, sand), it
    amplifies the round-off of :math:`\det F` by :math:`1/J`: at :math:`J = 10^{-8}` from entries of order 1 a change
    of 1e-15 moves the stress by 1e-9 of itself, and no correct code rounds alike."""
    patterns = (np.indices(F.shape[1:]).sum(axis=0) % 2 * 2.0 - 1.0,
                np.random.default_rng(0).choice([-1.0, 1.0], size=F.shape[1:]))
    tau = stress(F)
    scale = np.maximum(np.abs(tau).max(axis=(1, 2)), np.abs(floor_stress).max(axis=(1, 2)))
    keep = np.all(np.isfinite(tau), axis=(1, 2))
    for pattern in patterns:
        moved = np.abs(stress(F * (1.0 + CONDITION_PROBE * pattern)) - tau).max(axis=(1, 2))
        keep &= moved <= CONDITION_BOUND * scale
    return keep


# ------------------------------------------------------------------------------------------- plasticity
def snow_yield_states(material, rng, dim):
    r"""``[(F, Jp or None, note)]`` of snow at its yield surface: singular values exactly on
    :math:`1 + \theta_s` and :math:`1 - \theta_c`; past each by each offset :math:`\delta` of :data:`YIELD_OFFSETS`
    (:math:`(1 + \theta_s)(1 + \delta)`, :math:`(1 - \theta_c)(1 - \delta)`) and inside by it; and :math:`J_P` at its
    lower clamp with a compression past the bound (:math:`J_P` clamps)."""
    hi, lo = 1.0 + material.theta_s, 1.0 - material.theta_c
    pad = [1.0] * (dim - 2)
    out = [(_spectral(rng, [hi, lo] + pad), None, "σ on both bounds")]
    for d in YIELD_OFFSETS:
        out += [(_spectral(rng, [hi * (1 + d), 1.0] + pad), None, f"σ₁ past 1 + θs by {d:.0e}"),
                (_spectral(rng, [1.0, lo * (1 - d)] + pad), None, f"σ₂ past 1 - θc by {d:.0e}"),
                (_spectral(rng, [hi * (1 - d), lo * (1 + d)] + pad), None, f"inside both bounds by {d:.0e}")]
    out.append((_spectral(rng, [1.0, lo * 0.99] + pad), material.Jp_min, "Jp = Jp_min, compressed past the bound"))
    return out


def sand_yield_states(material, rng, dim):
    r"""``[(F, None, note)]`` of sand at its Drucker–Prager cone: principal Hencky strains
    :math:`\epsilon = (c + t/d)\,\mathbf 1 + r\,\hat n` (cohesion :math:`c`, shifted trace :math:`t < 0`, unit deviator
    :math:`\hat n`) with :math:`r = -k\,t\,\alpha\,(1 + \delta)`, :math:`k = (d\lambda + 2\mu)/(2\mu)`, so that
    :math:`\delta\gamma = -k t \alpha \delta`: on the cone (:math:`\delta = 0`), past and inside it by each offset of
    :data:`YIELD_OFFSETS`; at the apex (:math:`\epsilon = c\,\mathbf 1`) and just in tension
    (:math:`\epsilon = (c + 10^{-9})\mathbf 1`, and with a deviator)."""
    k = (dim * material.lam + 2.0 * material.mu) / (2.0 * material.mu)
    n = np.zeros(dim)
    n[0], n[1] = 1.0, -1.0
    n /= np.linalg.norm(n)
    trace = -1e-2 * dim

    def strained(eps):
        return _spectral(rng, np.exp(eps))

    def on_cone(delta):
        return strained(material.cohesion + trace / dim - k * trace * material.alpha * (1 + delta) * n)

    out = [(on_cone(0.0), None, "on the cone (δγ = 0)")]
    for d in YIELD_OFFSETS:
        out += [(on_cone(d), None, f"past the cone by {d:.0e}"), (on_cone(-d), None, f"inside the cone by {d:.0e}")]
    apex = np.full(dim, material.cohesion)
    out += [(strained(apex), None, "at the apex"), (strained(apex + 1e-9), None, "in tension by 1e-9"),
            (strained(apex + 1e-9 + 1e-3 * n), None, "in tension, with a deviator")]
    return out


YIELD_STATES = {SnowPlasticity: snow_yield_states, DruckerPragerSand: sand_yield_states}


def yield_state(scene, flat, rng, dtype):
    """The ``yield-surface`` state: the extreme rows of each plastic material at the rungs of its
    :data:`YIELD_STATES` family."""
    n = len(flat["x"])
    notes = [None] * n
    rows = extreme_rows(n)
    for index, m in enumerate(scene.material_list):
        family = YIELD_STATES.get(type(m))
        if family is None:
            continue
        ladder = family(m, rng, scene.dim)
        for k, p in enumerate(rows[flat["material"][rows] == index]):
            F, Jp, note = ladder[k % len(ladder)]
            flat["F"][p] = F
            if Jp is not None:
                flat["Jp"][p] = Jp
            notes[p] = note
    return flat, notes


# -------------------------------------------------------------------------------------------- positions
def exactly_at(target, origin, dx, dtype, below=False):
    r"""A position (float64, representable in ``dtype``) whose grid coordinate :math:`(x - o)/\Delta x`, computed as
    the reference computes it (:func:`mpmref.physics.kernels.compute_stencil`) in ``dtype``, is the smallest at or above
    ``target`` (``target`` itself wherever a position gives it exactly, as every position does on a grid of a
    power-of-two cell size and a whole-cell origin), or with ``below`` the largest below it (the highest position a
    kernel allows): :math:`o + t\,\Delta x` itself where it gives ``target`` exactly, else found by bisection between
    the representable positions around it."""
    t = np.dtype(dtype).type

    def coordinate(x):
        return (x - t(origin)) / t(dx)

    width = 8 * np.spacing(t(abs(origin) + abs(target * dx)))  # a few ulps of the numbers the coordinate is made of
    lo = hi = t(origin + target * dx)
    if not below and coordinate(lo) == target:
        return float(lo)
    while coordinate(lo) >= target:
        lo, width = t(lo - width), 2 * width
    while coordinate(hi) < target:
        hi, width = t(hi + width), 2 * width
    while True:  # bisect to two neighbouring positions on either side of the target
        mid = t(lo + (hi - lo) / 2)
        if not lo < mid < hi:
            return float(lo if below else hi)
        lo, hi = (lo, mid) if coordinate(mid) >= target else (mid, hi)


def _stencil_nodes(scene, x):
    """The linear indices (n, K) of every node of each position's stencil (weights zero or not): its base node as
    :func:`~mpmref.physics.kernels.compute_stencil` finds it, plus each offset."""
    grid, kernel, x = scene.grid, scene.kernel, np.atleast_2d(x)
    base = kernel.base_node((x - np.asarray(grid.origin, dtype=x.dtype)) / x.dtype.type(grid.dx))
    offsets = stencil_offsets(scene.dim, kernel.support)
    return (base[:, None, :] + offsets[None, :, :]) @ np.asarray(grid.strides)


def _massive_nodes(scene, flat, drawn):
    """Whether each node holds mass from the particles ``drawn`` (a boolean array over the nodes)."""
    nodes = _stencil_nodes(scene, flat["x"][drawn]).ravel()
    full = np.zeros(scene.grid.n_nodes, dtype=bool)
    full[nodes] = True
    return full


def on_grid_lines(scene, flat, rng, dtype):
    """The ``on-nodes-and-faces`` state: each extreme row moved from its drawn position onto, in turn, the nearest node
    (every coordinate a whole number of cells), a face (one coordinate, the others drawn) and, where it differs from a
    face, the kernel's base switch (one coordinate at a whole number plus the kernel's base shift, where
    ``floor(xi - shift)`` changes); a position is kept only where every node of its stencil holds mass from the drawn
    rows (else the next drawn position is tried)."""
    grid, kernel = scene.grid, scene.kernel
    n, dim = flat["x"].shape
    rows = extreme_rows(n)
    drawn = np.setdiff1d(np.arange(n), rows)
    massive = _massive_nodes(scene, flat, drawn)
    shifts = [("node", 0.0, dim), ("face", 0.0, 1)] + ([("base switch", kernel.base_shift, 1)]
                                                       if kernel.base_shift % 1 else [])
    notes = [None] * n
    anchors = iter(np.concatenate([flat["x"][rows], flat["x"][drawn]]))
    for k, p in enumerate(rows):
        kind, shift, axes = shifts[k % len(shifts)]
        for anchor in anchors:
            placed, where = _snapped(anchor, grid, shift, axes, (k // len(shifts)) % dim, dtype)
            if massive[_stencil_nodes(scene, placed)].all():
                flat["x"][p] = placed
                notes[p] = f"on a {kind}: {where}"
                break
    return flat, notes


def _snapped(anchor, grid, shift, axes, first_axis, dtype):
    """``anchor`` with ``axes`` coordinates (from ``first_axis`` on) at the nearest whole number of cells plus
    ``shift``, exactly (:func:`exactly_at`), and a note of where."""
    x = np.array(anchor, dtype=float)
    xi = (x - grid.origin) / grid.dx
    moved = []
    for a in [(first_axis + j) % len(x) for j in range(axes)]:
        target = np.round(xi[a] - shift) + shift
        x[a] = exactly_at(target, grid.origin[a], grid.dx, dtype)
        moved.append(f"xi{a} = {target:g}")
    return x, ", ".join(moved)


#: how far inside the lowest and highest positions a kernel allows the ``domain-edge`` rows of a kernel whose gradient
#: does not vanish with its weight lie (:func:`edge_gap`), in cells: 2^-9, a weight above ``MIN_WEIGHT``
EDGE_GAP = 2.0**-9


def edge_gap(kernel):
    r"""How far inside its allowed range a ``domain-edge`` row of ``kernel`` lies: 0 where the weight that vanishes at
    the range's ends has a vanishing slope too (the B-splines), :data:`EDGE_GAP` where it does not (the linear hat).
    There a node of weight one ulp has a gradient of :math:`1/\Delta x`: its velocity is its force over a mass a
    particle's ulp, and a step amplifies the round-off of that node by the inverse (two correct codes' float32 steps
    differed by 0.25 in :math:`F`); and a zero weight would read a node without mass through its gradient."""
    fx = np.array([[kernel.low_margin - np.floor(kernel.low_margin - kernel.base_shift)]])
    w, dw = kernel.weights(fx)
    return EDGE_GAP if np.any((w == 0.0) & (dw != 0.0)) else 0.0


def holds_for(extreme, kernel):
    """Whether ``extreme`` holds for ``kernel``: Δt at the stability limit and the many steps from rest not for a
    kernel whose gradient does not vanish with its weight (:func:`edge_gap`, the linear hat). A drawn weight of 1e-3
    puts a node of that share of a particle's mass under a full gradient: at the limit a 1e-15 change of the state
    moved ``F`` by 2.4e-12 (PIC, 3D); and a block whose particles cross cells rings: a pushed one (PIC, classic force)
    blew up at step 68 of 80 at the rest CFL number."""
    return not ((extreme.cfl is not None) and edge_gap(kernel))


def at_domain_edge(scene, flat, rng, dtype):
    """The ``domain-edge`` state: each extreme row at the lowest position the kernel allows on one axis (grid coordinate
    exactly its ``low_margin``) or the highest (just below ``cells - high_margin``), each moved in by :func:`edge_gap`,
    the axis and side cycling, its other coordinates drawn; in the walls' band, with its velocity on that axis turned
    outward."""
    grid, kernel = scene.grid, scene.kernel
    n, dim = flat["x"].shape
    notes = [None] * n
    gap = edge_gap(kernel)
    for k, p in enumerate(extreme_rows(n)):
        axis, upper = (k // 2) % dim, k % 2 == 1
        bound = grid.cells[axis] - kernel.high_margin - gap if upper else kernel.low_margin + gap
        flat["x"][p, axis] = exactly_at(bound, grid.origin[axis], grid.dx, dtype, below=upper)
        flat["v"][p, axis] = abs(flat["v"][p, axis]) * (1.0 if upper else -1.0)
        notes[p] = f"at the {'upper' if upper else 'lower'} edge of axis {axis}, moving out"
    return flat, notes


# ------------------------------------------------------------------------------------------------- grid
def massless_neighbours(scene, flat, rng, dtype):
    """The ``massless-neighbours`` grid state: the nodes of odd index sum empty, so that every node with mass has
    empty neighbours, and every seventh node with mass nearly empty (its mass and momentum times 1e-12)."""
    index = np.indices(scene.grid.node_shape).reshape(scene.dim, -1).sum(axis=0)
    empty = index % 2 == 1
    for key in ("grid_mass", "grid_momentum", "grid_force"):
        flat[key][empty] = 0.0
    tiny = np.flatnonzero(~empty & (flat["grid_mass"] > 0))[::7]
    for key in ("grid_mass", "grid_momentum", "grid_force"):
        flat[key][tiny] *= 1e-12
    return flat, None


# ------------------------------------------------------------------------------------------------- rest
def at_rest_block(scene, flat, rng, dtype, pushed=False):
    r"""The ``from-rest`` state: the particles on a lattice of two per cell and axis, in a block of whole cells at the
    middle of the box and, unless ``pushed``, on its lowest face along gravity (its lowest row's stencil reaching the
    walls' band, ``width`` nodes); at rest:
    :math:`F = I`, :math:`J = J_P = 1`, :math:`C = 0`, no PolyPIC modes, and :math:`v = 0`, or, ``pushed``,
    :math:`v_0 = p\,c\,(1 + (y - \bar y)/L)`: a translation and a shear of :math:`p` = :data:`PUSH` of the rest wave
    speed :math:`c` over the block's height :math:`L` (every particle moves). A smaller push leaves the velocities
    below the round-off of the stress, :math:`\epsilon c` per step: a push of :math:`10^{-3} c` moved the affine
    matrices of two correct codes apart by 7e-13 of themselves in four steps."""
    grid, dim = scene.grid, scene.dim
    n = len(flat["x"])
    cells = _block_cells(n, dim)
    lattice = np.stack(np.meshgrid(*[np.arange(2 * c) for c in cells], indexing="ij"), axis=-1).reshape(-1, dim)
    start = (np.array(grid.cells) - cells) // 2
    if not pushed:
        down = int(np.argmax(np.abs(scene.gravity)))
        low = scene.boundary.width - 1 + int(np.ceil(scene.kernel.base_shift - 0.25))  # its lowest row's base node
        start[down] = low if scene.gravity[down] < 0 else grid.cells[down] - cells[down] - low  # in the band
    flat["x"] = grid.origin + (start + (lattice + 0.5) / 2.0) * grid.dx
    flat["v"] = np.zeros((n, dim))
    if pushed:
        height = flat["x"][:, 1] - flat["x"][:, 1].mean()
        flat["v"][:, 0] = PUSH * scene.max_wave_speed() * (1.0 + height / (cells[1] * grid.dx))
    for key in ("C", "modes"):
        if key in flat:
            flat[key] = np.zeros_like(flat[key])
    if "F" in flat:
        flat["F"] = np.broadcast_to(np.eye(dim), (n, dim, dim)).copy()
    for key in ("J", "Jp"):
        if key in flat:
            flat[key] = np.ones(n)
    return flat, None


def _block_cells(n, dim):
    """Cells per axis of a block holding ``n`` particles at two per cell and axis (:data:`BLOCK_CELLS`)."""
    cells = np.array(BLOCK_CELLS[dim])
    if int(np.prod(cells)) * 2**dim != n:
        raise ValueError(f"a block of {n} particles at two per cell and axis is not {cells.tolist()} cells")
    return cells


def pushed_block(scene, flat, rng, dtype):
    """:func:`at_rest_block` in the middle of the box, with the shear push."""
    return at_rest_block(scene, flat, rng, dtype, pushed=True)


# ------------------------------------------------------------------------------------------- the families
EXTREMES = {
    "rest": Extreme("rest", "F = I, rotations, diagonal F, equal and nearly equal singular values; J = 1 and 1 ± ε",
                    deformation_state(rest_gradients, rest_volumes)),
    "near-symmetric-F": Extreme("near-symmetric-F", "|S₀₁| from 1e-3 down to 1e-12",
                                deformation_state(near_symmetric_gradients, None)),
    "collapse": Extreme("collapse", "J → 0⁺ (1e-2 to 1e-8), inverted F where the stress is finite; fluid J to 1e-4",
                        deformation_state(collapse_gradients, collapse_volumes)),
    "yield-surface": Extreme("yield-surface", "on, just past and just inside the yield surface (1e-10 to 1e-7)",
                             yield_state),
    "on-nodes-and-faces": Extreme("on-nodes-and-faces", "particles exactly on nodes, faces and base switches",
                                  on_grid_lines, exact_grid=True, float32=False),
    "domain-edge": Extreme("domain-edge", "particles at the lowest and highest positions, in the walls' band",
                           at_domain_edge, exact_grid=True, float32=False),
    "massless-neighbours": Extreme("massless-neighbours", "nodes with mass beside nodes without, nearly empty nodes",
                                   massless_neighbours, grid=True),
    "cfl-limit": Extreme("cfl-limit", "Δt at the scheme's measured stability limit", cfl="limit", float32=False),
    "from-rest": Extreme("from-rest", "F = I, v = 0 on the floor under gravity", at_rest_block, multi_step=True,
                         cfl="rest", float32=False),
    "pushed-from-rest": Extreme("pushed-from-rest", f"F = I, pushed by {PUSH:g} c and sheared", pushed_block,
                                multi_step=True, cfl="rest", float32=False),
    "large-stiffness": Extreme("large-stiffness", f"the materials {STIFFNESS_FACTOR:g} times stiffer"),
}
