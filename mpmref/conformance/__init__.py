r"""Conformance harness: check any MPM backend stage by stage against the NumPy reference.

A backend is trusted when it reproduces the reference on seeded random states, stage by stage and for
whole steps (``docs/conformance.md``). This package generates those states, runs a candidate on them and
reports the relative error of every output; it also exports the states and the reference's outputs as
``.npz`` files so that code in another language can check itself.

Stages and their signatures (those of :class:`mpmref.backends.numpy.NumpyBackend`)
----------------------------------------------------------------------------------
* ``stress(particles) -> tau (n, d, d)``: Kirchhoff stress of every particle, through its material;
* ``return_map(particles, wave_speed=None) -> Particles``: plastic projection (identity for elastic materials); with
  the optional output ``wave_speed`` (a float64 array the harness passes where the backend takes it), each particle's
  wave speed in its new state, compared like every output;
* ``p2g(particles) -> GridState(mass (N,), momentum (N, d), force (N, d))``, the stress computed inside, or given
  as ``p2g(particles, stress=tau)`` to a P2G that has a ``stress`` parameter;
* ``p2g_fused(particles, dt) -> GridState(mass, momentum = (mv)_i + Δt f_i)`` (optional), given the stress as
  ``p2g`` is;
* ``grid_update(grid_state, dt, time) -> (v, v_tilde)``, both (N, d);
* ``g2p(particles, v, v_tilde, dt) -> Particles``;
* ``step(particles, dt, time) -> Particles``: P2G, grid update, G2P and return map;
* ``ledger(particles, dt, time) -> {"ledger_<column>": float, ..., "energy_scale": float}``: the energy ledger of
  that step (:class:`mpmref.observe.ledger.EnergyLedger`, docs/energy_ledger.md), computed from the candidate's stage
  outputs, and the energy scale :math:`S = K + \Psi + |U|` of the input state.

The stages asynchronous stepping adds (:data:`ASYNC_CONFORMANCE_STAGES`): ``wave_speeds(particles, idx) -> (m,)``,
``p2g_classes`` (``p2g(particles, classes=classes)``, each particle class summed apart: ``class_sums``),
``interface_kicks(grid_state, dt, kappa) -> (2, N, d)`` and ``g2p_kicks`` (``g2p(..., kicks=(classes, kicks))``, which
also returns each particle's impulse and its moment). Backends that couple rigid bodies by CPIC also have the stages
``cpic_field``, ``cpic_tags``, ``cpic_p2g``, ``cpic_g2p`` and ``cpic_step`` (2D and 3D, float64; :mod:`.cpic`), which
run the backend from flat inputs to flat outputs. ``make_cases`` gives the cases of both when asked for them
(``stages=ALL_CONFORMANCE_STAGES``).

Grid arrays have one row per node in C order (node ``(i_0, .., i_{d-1})`` is row ``sum_a i_a stride_a``,
``stride_a = prod_{b>a} (cells_b + 1)``, at ``origin + i dx``). Particle outputs are compared on the
fields a stage may change (``x, v, C, F, J, Jp, modes``, those allocated and those the candidate evolves); ``F``, ``J``
and ``Jp`` only on the particles whose material evolves them, grid velocities only on the nodes with mass
(:mod:`.diagnosis`).

A candidate is one of
---------------------
* a backend reference of :mod:`mpmref.backends` (``"numba"``, an installed plugin's name, ``"MODULE:ATTRIBUTE"``);
* a factory ``factory(scene)`` returning an object with stage methods (a backend class is one) or a
  mapping ``{stage name: callable}``; it is called once per distinct scene;
* a mapping ``{stage name: callable}`` whose callables take the scene first, e.g.
  ``{"stress": lambda scene, particles: ...}``.

What a candidate implements, and nothing else, is checked
---------------------------------------------------------
A backend declares what it implements (:class:`mpmref.backends.capabilities.Implements`, on its class, its object or
its factory; a factory function that declares nothing is asked through the object it makes). A case applies when the
candidate implements what its stage depends on (:data:`.case.STAGE_PARTS`: the stress sees the materials, not the
walls; the grid update the walls, not the scheme), its factory makes the case's scene (one that raises
:class:`NotImplementedError` declines it) and it provides the stage. Every other case is *not applicable*, with its
reasons ("needs the cubic kernel", "compares F: this backend evolves C, J only", "does not provide the optional stage
p2g_fused"): never a failure. The catalogue is fitted to the declaration (:mod:`.cases`): the per-method cases run on
the materials the backend has, with the parameters it fixes.

Cases from the user's scene
---------------------------
:func:`scene_cases` draws every stage that a scene's steps call from that scene (:mod:`.scenes`): its method,
materials, walls, colliders, gravity and dtype, at its scales, in small boxes at its cell size (``mpmref conformance
check --scene SCENE.toml``).

Which built-in cases, and why not the full cross product
--------------------------------------------------------
Each stage is checked on the axes its result depends on, in 2D and 3D, with 64 (2D) or 128 (3D) particles at
least two cells from the domain faces, on a box whose cell counts per axis, cell size and origin, and with a Δt
and a time, that each case draws from its name (:mod:`.cases`, :mod:`.states`):

* ``stress``: each material alone and all five together (per-particle material dispatch). The stress does
  not depend on the scheme, kernel or boundary.
* ``return_map``: snow, sand and all five together; for the elastic materials it is the identity, which
  the full-step cases check.
* ``p2g`` and ``g2p``: every valid scheme x force x kernel (20 combinations), with a solid and the fluid
  mixed so that both the ``F`` and the ``J`` update run; then each material alone and all five together
  (MLS-MPM), so that a code with one material has cases. The material only enters P2G through the stress,
  which has its own cases.
* ``grid_update``: each wall type on all faces (sticky, slip, separate with friction, separate without friction,
  open), a different type on each face, and one collider of each shape (two moving, at ``time > 0``) with open walls.
  The grid update does not depend on the scheme or the material.
* ``p2g_fused`` (optional, :class:`mpmref.backends.base.FusedBackend`): the P2G cases without FLIP, compared with
  the reference's unfused momentum plus Δt times its force;
* ``step``: every valid method (as for P2G) and each material set (with MLS-MPM), with gravity and the
  mixed walls: the stages composed, return map included.
* ``ledger``: the step's cases, and MLS-MPM with one collider of each shape (two moving) and open walls.

That is 304 float64 cases instead of 20 x 6 x 6 x 2 per stage. The states are physically sensible: ``F``
a random rotation times a near-identity stretch with ``det F > 0.3`` (some inside, some outside the
plastic yield surfaces), ``J`` and ``Jp`` near 1, velocities of order 1, ``C`` of order 4 (the grid's
velocity gradients), PolyPIC modes scaled by ``dx^-degree``; the grid update gets a random grid state
with a quarter of the nodes empty.

The error
---------
For each output array, ``max|candidate - reference| / max|reference|`` over all its entries (with a
denominator of 1 where the reference is all zero; shape mismatch or a non-finite value: ``inf``); a
case's error is the largest over its outputs and it passes when that is ``<= rtol`` (default 1e-12 in
float64). A ledger term is a difference of energies, so its error is :math:`|a - r| / S` with the reference's
energy scale :math:`S` (:func:`.report.output_scale`): a term theory puts at zero is round-off of :math:`S`. See
:func:`.report.relative_error`. A failed case prints every output's error and what it ran on (method, materials with
their parameters, walls, Δt, time), and names its worst particle or node and, when the error is one factor everywhere,
that factor (:mod:`.diagnosis`).
"""

from .cases import ConformanceCase, make_cases, valid_methods
from .cli import add_parser
from .measures import relative_error
from .report import CaseResult, NotApplicable, Report, check, stage_functions
from .scenes import scene_cases
from .stages import ALL_CONFORMANCE_STAGES, ASYNC_CONFORMANCE_STAGES, CONFORMANCE_STAGES, CPIC_CONFORMANCE_STAGES
from .vectors import export, load_vectors

__all__ = ["ALL_CONFORMANCE_STAGES", "ASYNC_CONFORMANCE_STAGES", "CPIC_CONFORMANCE_STAGES", "CONFORMANCE_STAGES",
           "CaseResult", "ConformanceCase", "NotApplicable", "Report", "add_parser", "check", "export", "load_vectors",
           "make_cases", "relative_error", "scene_cases", "stage_functions", "valid_methods"]
