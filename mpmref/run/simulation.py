"""Simulation: particle state + stepper + backend + outputs + diagnostics."""

import time as _time
import warnings
from dataclasses import replace
from functools import cached_property, partial

import numpy as np

from ..backends import describe, make_backend, residency
from ..errors import AllParticlesLeftError, DomainExitError, InstabilityError, MpmrefError, NonFiniteError
from ..io.run_output import RunOutput
from ..observe.diagnostics import carried, carried_keys, diagnostics, polypic_mode_norms
from ..observe.ledger import book_exchange
from ..physics.materials import material_groups
from ..rigid.dynamics import current_shapes
from ..rigid.trimesh import TriMesh
from ..scene.sampling import sample_particles
from ..steppers import make_stepper
from ..steppers.limits import cfl_time_step, signal_speeds
from . import arguments
from .domain import apply_domain_exit, outside
from .emitters import due_now, emit, release_template, released, with_emitters
from .stability import StabilityWarning, above_limit_text, first_unbounded, warn_if_above_limit, within_margin

#: what a run records of the particles exchanged: those released by emitters, and those deleted at the domain's edge
DIRECTIONS = ("entered", "left")


class Simulation:
    """Run a :class:`~mpmref.scene.Scene` on a backend.

    Parameters
    ----------
    scene : Scene
        The validated scene.
    backend : str, callable or backend object
        A backend reference (:mod:`mpmref.backends`): ``"numpy"`` (the reference), ``"numba"``, an installed
        plugin's name, ``"MODULE:ATTRIBUTE"``, a factory ``f(scene) -> backend`` or a backend object made for
        ``scene``. It is checked against the scene before any work (:class:`~mpmref.errors.BackendError` names a
        missing stage and its signature).
    out_dir : str or pathlib.Path or None
        Where VTK series, ``diagnostics.csv`` and checkpoints go; None writes nothing.
    particles : Particles
        Initial state (default: sampled from the scene's bodies).
    hooks : Hooks
        Additions to the step (:class:`mpmref.steppers.Hooks`; default none).

    Notes
    -----

    ``sim.state`` is the whole :class:`~mpmref.state.State` (particles with stable ids, clock, stepper
    state). The particle arrays are readable and settable as ``sim.x``, ``sim.v``, ``sim.C``, ``sim.F``,
    ``sim.J``, ``sim.mass``, ``sim.vol0``; ``sim.id`` is each particle's stable identity. A step (a
    synchronous step, or one synchronised interval of asynchronous stepping) builds a new state; the
    current one is replaced only when the new one is finite and inside the domain, so after an error
    ``sim`` holds the last good state.

    With a backend that keeps the particles in its own memory (a GPU's: :mod:`mpmref.backends.residency`), a
    synchronous run without step hooks keeps them there from step to step (``sim.resident``); ``sim.state``,
    ``sim.particles`` and ``sim.x`` and the like are then host copies, made when read (once per step at most), and
    a change reaches the run by assignment (``sim.x = ...``, ``sim.particles = ...``, ``sim.state = ...``), not by
    writing into a copy's arrays.
    """

    def __init__(self, scene, backend="numpy", out_dir=None, particles=None, hooks=None):
        self.scene = scene
        self.backend = make_backend(backend, scene)
        self._backend_reference = backend
        self.stepper = make_stepper(scene, self.backend, hooks)
        #: whether the particles stay in the backend's memory from step to step (mpmref.backends.residency): a
        #: resident backend, a stepper with one Δt for every particle, no step hooks (Python functions of host arrays)
        self.resident = residency.resident(self.backend) and self.stepper.uniform_step and hooks is None
        #: where the particles are kept, asked alike of every backend (:func:`mpmref.backends.residency.memory_of`)
        self.memory = residency.memory_of(self.backend, self.resident, self._cfl_signal_speeds())
        if getattr(self.stepper, "ledger", None) is not None:
            self.stepper.ledger = self.memory.observer(self.stepper.ledger)
        self._host = self._signal_speed = None  # the state's host copy (a resident run's); its largest c_p + |v_p|
        state = self.stepper.initial_state(particles if particles is not None else sample_particles(scene))
        self.state = with_emitters(scene, state)
        self._releases = [release_template(scene, e) for e in scene.emitters]
        self.output = RunOutput(out_dir, scene) if out_dir is not None else None
        self.last_dt = None
        self.last_updates = 0
        self._last_bounded = None  # (state, meta) before an unbounded step, while no bounded step followed

    @cached_property
    def backend_info(self):
        """The backend's name (as given), class and version (:func:`mpmref.backends.describe`), for summaries."""
        return describe(self._backend_reference, self.backend)

    # ------------------------------------------------------------------------ state access
    @property
    def state(self):
        """The whole :class:`~mpmref.state.State`, with NumPy particle arrays (a resident run's host copy)."""
        if self._host is None or self._host[0] is not self._state:
            self._host = (self._state, self.memory.host_state(self._state))
        return self._host[1]

    @state.setter
    def state(self, value):
        self._state = self.memory.device_state(value)
        self._signal_speed = None

    @property
    def particles(self):
        return self.state.particles

    @particles.setter
    def particles(self, value):
        self.state = replace(self._state, particles=value)

    @property
    def step_count(self):
        return self._state.step

    @property
    def time(self):
        return self._state.time

    @property
    def deleted(self):
        return self._state.deleted

    @property
    def clamped(self):
        return self._state.clamped

    @property
    def id(self):
        """Stable integer identity of each particle (kept through deletion, reordering and restarts)."""
        return self._state.particles.id

    def _particle_field(name):
        def getter(self):
            return getattr(self.particles, name)

        def setter(self, value):
            old = getattr(self.particles, name)
            if old is None:
                raise AttributeError(f"this scene does not allocate '{name}'")
            value = np.asarray(value, dtype=old.dtype)
            if value.shape != old.shape:
                raise ValueError(f"'{name}' must have shape {old.shape}, got {value.shape}")
            self.particles = self.particles.with_(**{name: value.copy()})

        return property(getter, setter)

    x = _particle_field("x")
    v = _particle_field("v")
    C = _particle_field("C")
    F = _particle_field("F")
    J = _particle_field("J")
    mass = _particle_field("mass")
    vol0 = _particle_field("vol0")
    del _particle_field

    @property
    def n_particles(self):
        return self._state.particles.n

    @property
    def inertia(self):
        r"""The affine inertia :math:`D_p = D` of the scene's kernel (:math:`\Delta x^2/4` quadratic,
        :math:`\Delta x^2/3` cubic), or ``None`` where it is not constant (the linear hat)."""
        factor = self.scene.kernel.inertia_factor
        return None if factor is None else factor * self.scene.grid.dx**2

    def diagnostics(self):
        """Mass, momentum, angular momentum and energies of the current state (dict); in a scene whose particles can
        enter or leave (:func:`exchanges_particles`), what entered and left since the start (:meth:`exchanged`)."""
        d = self._measure(diagnostics, self.particles)
        return {"step": self.step_count, "time": self.time, **d, "deleted": self.deleted, "clamped": self.clamped,
                **self.exchanged(), **self.stepper.diagnostics(self.state)}

    def _measure(self, function, particles):
        """``function(particles, materials, gravity, inertia, mode_norms)`` of the scene
        (:func:`~mpmref.observe.diagnostics.diagnostics` or :func:`~mpmref.observe.diagnostics.carried`)."""
        kernel, grid = self.scene.kernel, self.scene.grid
        norms = polypic_mode_norms(particles, kernel, grid) if particles.modes is not None else None
        return function(particles, self.scene.material_list, self.scene.gravity, self.inertia, norms)

    def exchanged(self):
        """What entered the run (released by ``[[emitters]]``) and left it (deleted at the domain's edge) since its
        start, as ``entered_<key>`` and ``left_<key>`` (the keys of :func:`~mpmref.observe.diagnostics.carried_keys`:
        particles, mass, momentum, energy); empty in a scene whose particles can neither enter nor leave."""
        if not exchanges_particles(self.scene):
            return {}
        keys = carried_keys(self.scene.dim)
        return {f"{direction}_{key}": float(value) for direction in DIRECTIONS
                for key, value in zip(keys, self._state.stepper.get(direction, np.zeros(len(keys))))}

    def _booked(self, stepper, direction, particles):
        """The state's stepper arrays ``stepper`` with what ``particles`` carry
        (:func:`~mpmref.observe.diagnostics.carried`) added to the run's record of what ``direction``
        (``"entered"``, ``"left"``), and with an energy ledger, their energy booked to its ``inflow`` or ``outflow``
        (:func:`~mpmref.observe.ledger.book_exchange`). Checkpoints carry both."""
        record = self._measure(carried, particles)
        stepper = {**stepper, direction: stepper.get(direction, 0.0) + record}
        ledger = self.stepper.ledger
        if ledger is not None:
            stepper["energy_ledger"] = book_exchange(stepper.get("energy_ledger"), ledger.columns,
                                                     **{direction: record[-1]})
        return stepper

    # --------------------------------------------------------------------------- stepping
    def step(self, dt=None, t_end=None):
        """Advance one step and return the Δt used.

        Synchronous: one step of ``dt`` (default: the scene's fixed or CFL step, shortened so as not to pass
        ``t_end``). Asynchronous: one synchronised interval (every block steps until all particles meet
        again, ending at the first tick at or after ``t_end`` at the latest); ``dt`` must be ``None``. Releases of
        ``[[emitters]]`` due at the current time join first (:func:`mpmref.run.emitters.emit`). A ``dt`` that is not a
        finite number > 0, or a ``t_end`` that is not after the current time, raises
        :class:`~mpmref.errors.ArgumentError` (a ``ValueError``) before any work.
        """
        dt = None if dt is None else arguments.time_step(dt)
        t_end = None if t_end is None else arguments.end_time(t_end, self.time, after=True)
        if self.scene.emitters and due_now(self.scene, self._state):
            self._emit()  # releases due now join before the step
        if self.step_count == 0:
            first_dt = dt if dt is not None else self.stepper.time_step(self.particles)
            if first_dt is not None:
                warn_if_above_limit(self.scene, self.stepper.cfl_number(self.particles, first_dt))
        if dt is None:
            dt = self._time_step(t_end)
        new = self.stepper.advance(self._state, dt=dt, t_end=t_end)
        dt = new.time - self._state.time
        self.last_updates = self.stepper.updates(self._state, new)
        self._state = self._checked(new, dt)
        self.last_dt = dt
        return dt

    def _emit(self):
        """Append the releases due now (:func:`~.emitters.emit`) and book what they carry as entered."""
        before = self.state
        after = emit(self.scene, before, self._releases)
        if after is not before:
            after = replace(after, stepper=self._booked(after.stepper, "entered",
                                                        released(before.particles, after.particles)))
            self.state = after

    def _cfl_signal_speeds(self):
        r"""The CFL rule's :math:`c_p + |v_p|` of host particles (:func:`~mpmref.steppers.limits.signal_speeds`), or
        ``None`` where the run does not take Δt from it (a fixed ``time.dt``, or a stepper that sets its own)."""
        if self.scene.time.dt is not None or not self.stepper.uniform_step:
            return None
        return partial(signal_speeds, self.scene.material_list)

    def _time_step(self, t_end):
        r"""The run's Δt by the CFL rule (``None`` with a fixed ``time.dt`` or a stepper that sets its own, which the
        stepper takes): the stepper's rule (:mod:`mpmref.steppers.limits`) with :math:`\max_p(c_p + |v_p|)` of the
        state's summary, reduced where the particles are (:mod:`mpmref.backends.residency`), shortened so as not to
        pass ``t_end``."""
        t = self.scene.time
        if t.dt is not None or not self.stepper.uniform_step:
            return None
        if self._signal_speed is None:
            self._signal_speed = self.memory.summarize(self._state.particles).signal_speed
        dt = cfl_time_step(t.cfl, self.scene.grid.dx, self._signal_speed)
        return dt if t_end is None else min(dt, t_end - self.time)

    def _checked(self, new, dt):
        """The checks of the step to ``new``: its :class:`~mpmref.backends.residency.Summary` (reduced where the
        particles are) passes a finite step that stays inside the domain, bounded where the stepper has one Δt, as it
        is; any other goes through the host checks (:meth:`_check_finite`, :meth:`_check_bounded`, the domain policy)
        on host arrays, with their errors, warnings and last good state, and comes back to where the run keeps it."""
        summary = self.memory.summarize(new.particles, self._state.particles)
        lo, hi = self.scene.valid_region()
        uniform = self.stepper.uniform_step
        if (not summary.nonfinite and new.particles.n > 0 and summary.inside(lo, hi)
                and (not uniform or within_margin(summary.velocity_change, self.scene.dim, dt, self.scene.grid.dx))):
            self._last_bounded = None
            self._signal_speed = summary.signal_speed
            return new
        host = self.memory.host_state(new)
        self._check_finite(host.particles, dt)
        if uniform:
            self._check_bounded(host.particles, dt)
        host.particles = self._apply_domain_policy(host)
        self._signal_speed = None
        return self.memory.device_state(host)

    def _check_finite(self, new, dt):
        for name, arr in new.arrays().items():
            if arr.dtype.kind != "f" or np.isfinite(np.sum(arr)):
                continue  # a sum is finite unless an element is not (or it overflows: then look closer)
            bad = ~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1)
            if bad.any():
                cfl = self.stepper.cfl_number(self.particles, dt)
                raise NonFiniteError(step=self.step_count + 1, particle=int(new.id[np.argmax(bad)]), quantity=name,
                                     cfl=cfl, checkpoint=self._save_last_good("nonfinite"),
                                     cfl_note=above_limit_text(self.scene.method.scheme, cfl))

    def _check_bounded(self, new, dt):
        """Check a synchronous step for an unbounded velocity change (:func:`.stability.first_unbounded`).

        One that would meet a domain-exit policy (a particle of the new state is outside the valid region)
        raises :class:`InstabilityError`; one inside the domain is warned about once and the run goes on,
        because runs above the measured limits must go on for ``mpmref verify extremes`` to find them. The
        last good state stays the one before the unbounded step until a bounded step follows.
        """
        bad = first_unbounded(self.particles.v, new.v, dt, self.scene.grid.dx)
        if bad is None:
            self._last_bounded = None  # the new state passes: it becomes the last good one
            return
        cfl = self.stepper.cfl_number(self.particles, dt)  # per-particle wave speeds: only when it is reported

        def instability(checkpoint=None):
            return InstabilityError(self.step_count + 1, int(self.particles.id[bad[0]]), "v", cfl, checkpoint,
                                    what=f"unbounded velocity v (|Δv|·Δt = {bad[1]:.3g} cells in one step; at most "
                                    "1 is bounded)", cfl_note=above_limit_text(self.scene.method.scheme, cfl))

        first = self._last_bounded is None
        if first:
            self._last_bounded = (self.state, self._meta("instability"))
        if outside(new.x, *self.scene.valid_region()).any():
            raise instability(self._save_last_good("instability"))
        if first:
            warnings.warn(f"{instability()}; the run goes on while every particle stays inside the domain",
                          StabilityWarning, stacklevel=3)

    def _apply_domain_policy(self, new):
        """Apply ``boundary.domain_exit`` to the new state's particles; counts go into ``new``."""
        p = new.particles
        result = apply_domain_exit(p, *self.scene.valid_region(), self.scene.boundary.domain_exit)
        if result.outside.size and self.scene.boundary.domain_exit == "error":
            raise DomainExitError(self.step_count + 1, p.id[result.outside], p.x[result.outside],
                                  checkpoint=self._save_last_good("domain_exit"))
        if result.particles.n == 0:
            raise AllParticlesLeftError(self.step_count + 1, self.deleted + result.deleted,
                                        checkpoint=self._save_last_good("all_left"))
        new.clamped += result.clamped
        new.deleted += result.deleted
        if result.deleted:
            new.stepper = self._booked(new.stepper, "left", p.select(result.outside))
        return result.particles

    def _save_last_good(self, reason):
        if self.output is None:
            return None
        state, meta = self._last_bounded or (self.state, self._meta(reason))
        return self.output.save_checkpoint(state, {**meta, "reason": reason},
                                           path=self.output.dir / f"last_good_{reason}.npz")

    # ----------------------------------------------------------------------------- running
    def run(self, steps=None, until_step=None, t_end=None, progress=False, record=False, dt=None, each_step=None):
        """Run ``steps`` more steps, or until step ``until_step`` or time ``t_end`` (at most one of the three; default:
        the scene's ``time.steps`` or ``time.t_end``).

        One rule, the command line's too (``mpmref run --steps | --until-step | --t-end``): ``steps`` counts the
        steps to take now, ``until_step`` is the step count to stop at (a total, like the scene's ``time.steps``,
        so that a resumed run ends where the uninterrupted one does) and ``t_end`` the simulated time to stop at.
        ``run(steps=3)`` twice ends at step 6; ``run(until_step=3)`` twice ends at step 3.

        When the simulation has an output folder, writes a frame (and the checkpoint) every ``scene.output.every``
        steps and a row of ``diagnostics.csv`` every ``scene.output.diagnostics_every`` steps, both also at the
        start and the end. Returns a summary dict (steps, wall time, particle-steps/s, drifts); with ``record``, its
        ``"series"`` holds the diagnostics rows of this run at the same cadence (its first state, every
        ``diagnostics_every`` steps, its last state), with or without an output folder.

        ``dt`` fixes every step's Δt (as :meth:`step` takes it; default: the scene's rule, shortened so as not to
        pass ``t_end``). ``each_step(sim)``, if given, is called after every step, once the run's own outputs of
        that step are written; what it raises ends the run and propagates (as the step's own errors do). Negative
        ``steps`` or ``until_step``, a ``t_end`` before the current time (or not finite), a ``dt`` that is not a
        finite number > 0, or two stops at once raise :class:`~mpmref.errors.ArgumentError` (a ``ValueError``)
        before any work.
        """
        steps, t_end = self._resolve_stop(*arguments.stop(steps, until_step, t_end, self.step_count, self.time))
        dt = None if dt is None else arguments.time_step(dt)
        first = self.diagnostics()
        series = [first] if record else None
        if self.output is not None and self.step_count == 0 and not self.output.rows:
            self._write(frame=True, row=first)
        bar = _progress(steps, t_end, self.time, progress)
        start, done, particle_steps = _time.perf_counter(), 0, 0
        try:
            while not self._finished(done, steps, t_end):
                taken = self.step_clipped(t_end) if dt is None else self.step(dt, t_end)
                done += 1
                particle_steps += self.last_updates
                bar.update(1 if steps is not None else taken)
                self._write_due(series)
                if each_step is not None:
                    each_step(self)
        finally:
            bar.close()
        wall = _time.perf_counter() - start
        if done:
            self._write_due(series, end=True)
        summary = _summary(first, self.diagnostics(), done, wall, particle_steps, self.stepper.summary(self._state))
        return summary if series is None else {**summary, "series": series}

    def _write_due(self, series, end=False):
        """What is due at the current step: the frame (and checkpoint) every ``output.every`` steps and the
        diagnostics row every ``output.diagnostics_every`` steps, written to the output folder (if any) and the row
        appended to ``series`` (when recording). With ``end``, the ones the last step was not due for."""
        spec = self.scene.output
        frame, row = self.step_count % spec.every == 0, self.step_count % spec.diagnostics_every == 0
        if end:
            frame, row = not frame, not row
        values = self.diagnostics() if row and (self.output is not None or series is not None) else None
        if series is not None and values is not None:
            series.append(values)
        if self.output is not None:
            self._write(frame=frame, row=values)

    @property
    def compiles(self):
        """Whether :meth:`warm_up` has anything to compile (a compiled backend, or asynchronous bookkeeping)."""
        return hasattr(self.backend, "warm_up") or self.stepper.compiles

    def warm_up(self):
        """Compile the backend's kernels (and an asynchronous stepper's bookkeeping) for this scene, so that a timed
        run that follows does not time compilation; the state is not changed."""
        from ..steppers.pipeline import substep

        if hasattr(self.backend, "warm_up"):
            self.backend.warm_up(self.particles, substep)  # host particles; a resident backend moves them itself
        self.stepper.warm_up(self.particles)

    def step_clipped(self, t_end):
        """One step, shortened if the stepper can so as not to pass ``t_end``."""
        return self.step(t_end=t_end)

    def _resolve_stop(self, steps, t_end):
        if steps is None and t_end is None:
            steps = self.scene.time.steps
            if steps is not None:
                steps = max(0, steps - self.step_count)  # scene step counts are totals (resume-safe)
            t_end = self.scene.time.t_end
        if steps is None and t_end is None:
            raise MpmrefError("no stop given: set time.steps or time.t_end in the scene, or pass steps/t_end")
        return steps, t_end

    def _finished(self, done, steps, t_end):
        if steps is not None:
            return done >= steps
        return self.time >= t_end * (1.0 - 1e-12)

    # ------------------------------------------------------------------------------ outputs
    def point_data(self, fields=None):
        """Per-particle output arrays named as in ``scene.output.fields``, after ``id`` (int64, the stable
        identity of :attr:`id`, kept through deletion, reordering and asynchronous steps)."""
        fields = fields or self.scene.output.fields
        p = self.particles
        J = self.volume_ratio()
        data = {"velocity": p.v, "mass": p.mass, "volume": p.vol0 * J, "J": J,
                "material": p.material.astype(np.int32)}
        if "stress" in fields or "pressure" in fields:
            sigma = self.backend.stress(p) / self.elastic_volume_ratio()[:, None, None]
            data["stress"] = sigma
            data["pressure"] = -np.trace(sigma, axis1=1, axis2=2) / p.dim
        out = {"id": p.id, **{k: data[k] for k in fields}}  # the stable identity, for pathlines across frames
        if p.level is not None:  # asynchronous stepping: log2 of each particle's last step in ticks
            out["dt_level"] = p.level.astype(np.int32)
        if p.tag_A is not None:  # CPIC: tags packed as the reference does, distance and near flag
            out.update({"side": pack_tags(p.tag_A, p.tag_T), "distance": p.phi, "near": p.near.astype(np.int8)})
        return out

    def volume_ratio(self):
        """:math:`J = V/V^0` per particle: ``det F`` for elastic solids, ``det F_E * J_P`` for plastic
        ones (F holds the elastic part), the tracked ``J`` for fluids."""
        p = self.particles
        J = np.ones(p.n, dtype=p.x.dtype)
        for material, idx in material_groups(self.scene.material_list, p):
            if material.tracks == "J":
                J[idx] = p.J[idx]
            else:
                J[idx] = np.linalg.det(p.F[idx]) * (p.Jp[idx] if getattr(material, "plastic", False) else 1.0)
        return J

    def elastic_volume_ratio(self):
        r""":math:`J_E`, relating Kirchhoff and Cauchy stress (:math:`\sigma = \tau / J_E`): ``det F`` or the fluid's
        ``J``."""
        p = self.particles
        J = np.ones(p.n, dtype=p.x.dtype)
        for material, idx in material_groups(self.scene.material_list, p):
            J[idx] = p.J[idx] if material.tracks == "J" else np.linalg.det(p.F[idx])
        return J

    def grid_data(self):
        """Node mass and P2G velocity of the current particles over the scene's ``output.grid_region``:
        ``(first_node, node_shape, {"mass", "velocity"})``, arrays in C order over the region's nodes.

        ``"active"``: the smallest box of whole blocks (the grid's ``block``) that holds every node with mass,
        clipped to the grid; ``"all"``: every node. A backend with a sparse grid never builds the dense one
        for the active region.
        """
        gs = self.backend.p2g(self.particles, self.backend.prepare(self.particles))
        grid = self.scene.grid
        index = grid.node_indices() if gs.layout is None else gs.layout.node_index
        has = gs.mass > 0
        lo, hi = np.zeros(grid.dim, dtype=np.int64), np.array(grid.node_shape)
        if self.scene.output.grid_region == "active" and has.any():
            lo = index[has].min(axis=0) // grid.block * grid.block
            hi = np.minimum((index[has].max(axis=0) // grid.block + 1) * grid.block, hi)
        inside = np.all((index >= lo) & (index < hi), axis=1)
        at = np.ravel_multi_index(tuple((index[inside] - lo).T), tuple(hi - lo))
        velocity = np.where(has[:, None], gs.momentum / np.where(has, gs.mass, 1.0)[:, None], 0.0)
        data = {}
        for name, values in (("mass", gs.mass), ("velocity", velocity)):
            data[name] = np.zeros((int(np.prod(hi - lo)),) + values.shape[1:], dtype=values.dtype)
            data[name][at] = values[inside]
        return tuple(lo), tuple(hi - lo), data

    def write_output(self):
        """Write a particle frame (and grid frame), a diagnostics row and, if enabled, a checkpoint."""
        self._write(frame=True, row=self.diagnostics())

    def _write(self, frame, row):
        """Write a frame when ``frame``, the diagnostics ``row`` (a dict) unless it is ``None``, then, after a frame,
        the checkpoint if enabled (it carries every row written so far, so a resumed run writes the same rows)."""
        out = self.output
        if frame:
            rigid = self._state.rigid
            polylines = None if rigid is None else [(b.vertices, b.triangles if isinstance(b, TriMesh) else b.segments)
                                                    for b in current_shapes(self.scene.rigid_bodies, rigid)]
            out.write_frame(self.step_count, self.time, self.particles.x, self.point_data(),
                            self.grid_data() if self.scene.output.grid else None, polylines)
        if row is not None:
            out.write_diagnostics(row)
        if frame and self.scene.output.checkpoint:
            out.save_checkpoint(self.state, self._meta("output"))

    def save_checkpoint(self, reason="interrupted"):
        """Write the current state to the output folder's ``checkpoint.npz`` (e.g. on Ctrl-C); returns its path."""
        return self.output.save_checkpoint(self.state, self._meta(reason))

    def _meta(self, reason):
        return {"reason": reason, "scene": self.scene.fingerprint()}

    @classmethod
    def resume(cls, scene, out_dir, backend="numpy"):
        """Continue the run whose checkpoint is in ``out_dir`` (bit-identical to an uninterrupted run)."""
        sim = cls(scene, backend=backend, out_dir=out_dir, particles=None)
        path = sim.output.checkpoint_path
        if not path.exists():
            raise MpmrefError(f"no checkpoint to resume from: {path} does not exist")
        state, meta = sim.output.load_checkpoint()
        if meta["scene"] != scene.fingerprint():
            raise MpmrefError(f"checkpoint {path} was written by a different scene; refusing to resume")
        sim.state = state
        sim.output.restore(meta["output"])
        return sim


def pack_tags(A, T):
    """CPIC tags (n, nb) packed per particle as the reference code does: bit ``2r+1`` = A, bit ``2r`` = T (int32)."""
    shifts = 2 * np.arange(A.shape[1])
    return ((A.astype(np.int64) << (shifts + 1)) | (T.astype(np.int64) << shifts)).sum(axis=1).astype(np.int32)


def _progress(steps, t_end, t0, enabled):
    from tqdm import tqdm

    if steps is not None:
        return tqdm(total=steps, disable=not enabled, unit="step", dynamic_ncols=True)
    return tqdm(total=t_end - t0, disable=not enabled, unit="s(sim)", dynamic_ncols=True,
                bar_format="{l_bar}{bar}| t={n:.4g}/{total:.4g} [{elapsed}<{remaining}]")


def exchanges_particles(scene):
    """Whether particles can enter a run of ``scene`` (``[[emitters]]``) or leave it (``domain_exit = "delete"``)."""
    return bool(scene.emitters) or scene.boundary.domain_exit == "delete"


def exchanged_between(first, last, direction):
    """What entered (``direction`` ``"entered"``) or left (``"left"``) a run between its diagnostics rows ``first`` and
    ``last`` (:meth:`Simulation.exchanged`), by key: ``particles``, ``mass``, ``momentum_x``, ..., ``energy`` (empty
    when the rows have no such columns)."""
    prefix = f"{direction}_"
    return {k.removeprefix(prefix): last[k] - first[k] for k in first if k.startswith(prefix)}


def _summary(first, last, steps, wall, particle_steps, stepper_summary):
    r"""The run's summary from its ``first`` and ``last`` diagnostics rows: the drifts of what the run conserves, each
    against the start plus what entered minus what left between the two rows (:func:`exchanged_between`; nothing in a
    scene whose particles neither enter nor leave), and in such a scene those figures (``entered``, ``left``):

    .. math::

        \frac{M_1 - (M_0 + M_{in} - M_{out})}{M_0 + M_{in}}, \qquad
        \frac{\lVert P_1 - (P_0 + P_{in} - P_{out})\rVert}{\sqrt{2 \max(M_0, M_1) \max(K_0, K_1)}}, \qquad
        \frac{E_1 - (E_0 + E_{in} - E_{out})}{|E_0| + |E_{in}|},

    the momentum's relative to the total mass times the r.m.s. speed, :math:`K` the particles' kinetic energy in
    their velocity and :math:`E` the diagnostics' ``total_energy``."""
    entered, left = (exchanged_between(first, last, direction) for direction in DIRECTIONS)

    def expected_change(key):
        return entered.get(key, 0.0) - left.get(key, 0.0)

    def drift(key, record):
        a = first[key]
        return (last[key] - a - expected_change(record)) / max(abs(a) + abs(entered.get(record, 0.0)), 1e-300)

    axes = [k.removeprefix("momentum_") for k in first if k.startswith("momentum_")]
    p0, p1 = (np.array([row[f"momentum_{a}"] for a in axes]) for row in (first, last))
    p_in = np.array([expected_change(f"momentum_{a}") for a in axes])
    ref = max(np.sqrt(2 * max(first["mass"], last["mass"]) * max(first["kinetic"], last["kinetic"], 1e-300)), 1e-300)
    exchange = {"entered": entered, "left": left} if entered else {}
    return {
        "steps": steps, "wall_s": wall, "particle_steps_per_s": particle_steps / wall if wall > 0 else float("nan"),
        "mass_drift_rel": drift("mass", "mass"),
        "momentum_drift_rel": float(np.linalg.norm(p1 - p0 - p_in) / ref),
        "energy_drift_rel": drift("total_energy", "energy"), **exchange, "final": last, **stepper_summary,
    }
