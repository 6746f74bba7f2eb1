"""Exceptions raised by mpmref, each carrying what a user needs to act on it."""


class MpmrefError(Exception):
    """Base class of every error raised on purpose by mpmref.

    Every one pickles with its message and attributes (worker processes of the verification cases and studies send
    errors back), whatever its constructor's arguments: it is rebuilt without calling ``__init__`` again."""

    def __reduce__(self):
        return _rebuilt, (type(self), self.args, self.__dict__)


def _rebuilt(cls, args, attributes):
    """An error of class ``cls`` with the message arguments ``args`` and the attributes ``attributes``."""
    error = cls.__new__(cls)
    Exception.__init__(error, *args)
    error.__dict__.update(attributes)
    return error


class SceneError(MpmrefError, ValueError):
    """A scene field is missing, unknown, of the wrong type or out of its allowed range.

    Parameters
    ----------
    field : str
        Dotted path of the offending field, e.g. ``"materials.jelly.nu"``.
    value : object
        The value that was given.
    allowed : str
        Human description of what would have been accepted.
    """

    def __init__(self, field, value, allowed):
        self.field, self.value, self.allowed = field, value, allowed
        super().__init__(f"scene field '{field}' = {value!r} is invalid: allowed {allowed}")


class InstabilityError(MpmrefError):
    """A step blew up: its new state is not bounded (see :mod:`mpmref.run.stability`) or not finite.

    Raised before any domain-exit policy sees the new state. Attributes name the step, the first
    offending particle and quantity, and the CFL number ``dt * (c_max + |v|_max) / dx`` of the step that
    produced it; ``checkpoint`` is the path of the last good state (finite and bounded) written before
    raising (or ``None``).

    Parameters
    ----------
    step, particle : int
    quantity : str        the particle array found bad, e.g. ``"v"``
    cfl : float
    checkpoint : str or pathlib.Path or None
    what : str            what went wrong with the quantity (default: ``"unbounded <quantity>"``)
    cfl_note : str        how the CFL number compares with the measured stable limit (or ``""``)
    """

    def __init__(self, step, particle, quantity, cfl, checkpoint=None, what=None, cfl_note=""):
        self.step, self.particle, self.quantity, self.cfl = step, particle, quantity, cfl
        self.checkpoint = checkpoint
        where = f"; last good state saved to {checkpoint}" if checkpoint else ""
        note = f", {cfl_note}" if cfl_note else ""
        super().__init__(f"{what or 'unbounded ' + quantity} at step {step}, particle {particle} "
                         f"(CFL number of that step {cfl:.3g}{note}){where}")


class NonFiniteError(InstabilityError, FloatingPointError):
    """A non-finite value appeared in the particle state (an :class:`InstabilityError`)."""

    def __init__(self, step, particle, quantity, cfl, checkpoint=None, cfl_note=""):
        super().__init__(step, particle, quantity, cfl, checkpoint, what=f"non-finite {quantity}", cfl_note=cfl_note)


class DomainExitError(MpmrefError):
    """Particles left the region where their kernel stencil fits on the grid (policy ``error``)."""

    def __init__(self, step, particles, positions, checkpoint=None):
        self.step, self.particles, self.positions, self.checkpoint = step, particles, positions, checkpoint
        where = f"; last good state saved to {checkpoint}" if checkpoint else ""
        super().__init__(
            f"{len(particles)} particle(s) left the domain at step {step} "
            f"(first: index {particles[0]} at {positions[0].tolist()}); "
            f"set 'boundary.domain_exit' to 'clamp' or 'delete' to continue instead{where}"
        )


class AsyncCensusError(MpmrefError):
    """Asynchronous stepping lost or duplicated a particle id (checked at every synchronised time)."""

    def __init__(self, tick, lost, duplicated):
        self.tick, self.lost, self.duplicated = tick, lost, duplicated
        super().__init__(f"particle census failed at tick {tick}: {len(lost)} id(s) lost (first {list(lost[:5])}), "
                         f"{len(duplicated)} duplicated (first {list(duplicated[:5])})")


class TickTooLongError(MpmrefError):
    """A block's stability limit is shorter than one tick of asynchronous stepping."""

    def __init__(self, tick, particle, limit_s):
        self.tick, self.particle, self.limit_s = tick, particle, limit_s
        super().__init__(f"particle {particle} needs steps of at most {limit_s:.3g} s at tick {tick}, shorter than "
                         "one tick: lower 'time.tick'")


class AllParticlesLeftError(MpmrefError):
    """Every remaining particle left the domain in one step under ``domain_exit = "delete"``.

    The run stops there, because nothing is left to simulate. ``deleted`` counts every particle deleted
    since the start, ``step`` is the step at which the last ones left; the simulation keeps the state
    before that step, saved to ``checkpoint`` (or ``None`` without an output folder).
    """

    def __init__(self, step, deleted, checkpoint=None):
        self.step, self.deleted, self.checkpoint = step, deleted, checkpoint
        where = f"; last state with particles saved to {checkpoint}" if checkpoint else ""
        super().__init__(f"all particles have left the domain at step {step} ({deleted} deleted in all under "
                         f"boundary.domain_exit = 'delete'); nothing is left to simulate{where}")


class BackendError(MpmrefError):
    """A backend reference cannot be used: an unknown name, a module or attribute that cannot be imported, an
    object that is not a backend, or a backend lacking a stage (or a stage's arguments) that its scene needs.

    Raised before any work (:func:`mpmref.backends.make_backend`); the command line reports it with exit status 2.
    """


class NotImplementedByBackend(BackendError):
    """A backend does not implement what a scene needs: its declaration (:mod:`mpmref.backends.capabilities`) lacks
    it, its factory declined the scene (raised :class:`NotImplementedError`), or it lacks a stage that only some
    scenes need (asynchronous stepping, rigid bodies). The checks report such a scene as *not applicable*, with
    ``reasons``; a run of it is refused before any work (exit status 2).

    Parameters
    ----------
    backend : str       the backend's label
    scene : str         the scene's name
    reasons : list      what the scene needs that the backend lacks, each in words ("needs the cubic kernel")
    """

    def __init__(self, backend, scene, reasons):
        self.backend, self.scene, self.reasons = backend, scene, list(reasons)
        super().__init__(f"backend {backend!r} does not implement what scene {scene!r} needs: {'; '.join(reasons)}")


class ArgumentError(MpmrefError, ValueError):
    """An argument of the Python API is out of its range (a ``ValueError``), e.g. ``Simulation.step(dt=-0.01)``.

    Parameters
    ----------
    name : str
        The argument, e.g. ``"dt"``.
    value : object
        The value given.
    allowed : str
        What would have been accepted (:mod:`mpmref.run.arguments`).
    """

    def __init__(self, name, value, allowed):
        self.name, self.value, self.allowed = name, value, allowed
        super().__init__(f"{name} = {value!r} is invalid: allowed {allowed}")
