"""Each case on what the backend implements: its scenes fitted to the backend's declaration, the rest not applicable.

A backend declares what it implements (:class:`mpmref.backends.capabilities.Implements`; everything when it declares
nothing) and may decline a scene by probing (its factory raises :class:`NotImplementedError`). A case builds every
scene it runs through :func:`fit` (or a :class:`Triage`), saying with an :class:`~mpmref.backends.fitting.Allow` what
its claim lets change. The fitting itself is :mod:`mpmref.backends.fitting`, the one mechanism the conformance
catalogue uses too; in the words of the cases' claims:

* ``materials``: ``"substitute"``, a hyperelastic material the backend lacks becomes one it has, of the same density
  and rest P-wave speed (so the same CFL step), with the parameters the backend fixes: a claim that holds for any
  hyperelastic material (momentum conserved, no energy gain beyond the integrator's, a stability limit in CFL
  numbers) keeps its meaning, and every bound that depends on the material is computed from the scene, so from the
  substitute. ``"any"``: any material the backend has, plastic ones too (a claim that holds for every material:
  momentum conservation). ``"subset"``: only the bodies of the materials the backend has (a claim made material by
  material). Each of them gives a material of the backend's type the parameters the backend fixes.
* ``walls="open"``: open walls the backend lacks become frictionless walls of a type it has, on a domain padded on
  their side by the band of nodes they act on. Nothing reaches that band: its nodes hold no mass, so no particle
  reads them, and the run is the open one. ``walls="static"``: that, and an acting wall the backend lacks becomes a
  static wall it has (for a claim that holds for every static wall: no energy gain, stability, agreement with the
  reference).
* ``friction``: Coulomb friction the backend lacks is dropped. ``kernel`` and ``dtype``: another kernel or precision
  the backend has, for a claim whose bounds the case computes from the scene's kernel and machine epsilon. ``force``:
  another force discretisation, for a claim that holds for either (a scheme whose label does not name its force).
* ``dims``: the 3D slab of a 2D scene (:func:`mpmref.backends.fitting.lifted`), for a claim that holds in any
  dimension, on a backend without 2D.

The scheme is never changed: a claim about a scheme is checked on that scheme or not at all. What the fit cannot
give the backend is *not applicable*, with the reasons of :meth:`~mpmref.backends.capabilities.Implements.missing`
or of the backend's own refusal: a :class:`NotApplicable` item of the case's result (``result["not_applicable"]``),
never a failure, never an error. The changes of a fitted scene are sentences (:class:`Adaptation`,
``result["adapted"]``) that the reports print. A backend that implements a scene gets that scene unchanged, so a full
backend runs every case exactly as the case declares it. A case none of whose runs applies raises
:class:`NothingApplicable` with its items; :func:`require` does so for a case that runs only on backends implementing
every scene it declares as declared.
"""

from dataclasses import dataclass
from functools import lru_cache

from mpmref import Scene
from mpmref.backends import implements, make_backend
from mpmref.backends.fitting import ANYTHING, Allow, Fitted, Inapplicable, unmodelable
from mpmref.backends.fitting import fit as fit_declaration
from mpmref.errors import NotImplementedByBackend
from mpmref.physics.catalogue import MATERIALS

__all__ = ["ANYTHING", "HYPERELASTIC", "Adaptation", "Allow", "Fitted", "Inapplicable", "NotApplicable",
           "NothingApplicable", "Triage", "declaration_of", "fit", "require", "unmodelable"]

#: the materials whose stored energy is a function of the deformation alone (read from the material classes)
HYPERELASTIC = tuple(kind for kind, cls in MATERIALS.items() if cls.hyperelastic)


@dataclass(frozen=True)
class NotApplicable:
    """A check, or a run and the checks it carries, that the backend cannot do: its ``name`` and the ``reasons``
    (what the backend lacks, in words)."""

    name: str
    reasons: tuple

    @property
    def why(self):
        return "; ".join(self.reasons)


@dataclass(frozen=True)
class Adaptation:
    """The runs ``names`` of a case ran on a scene fitted to the backend: ``changes``, each a sentence."""

    names: tuple
    changes: tuple


class NothingApplicable(Exception):
    """No run of the case applies to the backend: the case is *not applicable*; ``items`` are its
    :class:`NotApplicable` items (picklable: the one argument is the tuple of items)."""

    def __init__(self, items):
        super().__init__(tuple(items))
        self.items = tuple(items)

    def __str__(self):
        return "; ".join(f"{i.name}: {i.why}" for i in self.items)


# ------------------------------------------------------------------------------------------------------ fitting
def fit(scene, backend, allow=Allow()):
    """The scene closest to ``scene`` that ``backend`` implements, within what ``allow`` lets change
    (:func:`mpmref.backends.fitting.fit` on the backend's declaration; a scene its factory declines is passed over).

    Parameters
    ----------
    scene : Scene or dict
        The case's scene, or its declaration (the TOML structure; relative paths resolve from the current folder).
    backend : str, callable or backend object
        A backend reference (:mod:`mpmref.backends`).
    allow : Allow
        What the case's claim lets change.

    Returns
    -------
    Fitted
        As :func:`mpmref.backends.fitting.fit` returns and raises.
    """
    scene = scene if isinstance(scene, Scene) else Scene.from_dict(scene)
    return fit_declaration(scene, declaration_of(backend), allow, accept=lambda s: _refuse_if_declined(backend, s))


def declaration_of(backend):
    """What ``backend`` declares it implements (:func:`mpmref.backends.implements`: a factory function that declares
    nothing is asked through an object it makes for a small probe scene)."""
    return _declaration(backend) if isinstance(backend, str) else implements(backend)


@lru_cache(maxsize=None)
def _declaration(reference):
    return implements(reference)


def _refuse_if_declined(backend, scene):
    """:class:`Inapplicable` with the backend's own reasons if making it for ``scene`` refuses the scene (its
    factory declined it, or it lacks a stage only such scenes need)."""
    try:
        make_backend(backend, scene)
    except NotImplementedByBackend as exc:
        raise Inapplicable(exc.reasons) from None


# ------------------------------------------------------------------------------------------------------ triage
class Triage:
    """Sorts a case's runs into those that run (on a fitted scene) and those not applicable, and keeps what it
    changed; ``record()`` gives the two lists for the case's result.

    Parameters
    ----------
    backend : str, callable or backend object
        The backend the case runs.
    """

    def __init__(self, backend):
        self.backend = backend
        self.not_applicable = []
        self._adapted = {}
        self._lacking = {}

    def fit(self, run, scene, allow=Allow()):
        """The scene of ``run`` fitted to the backend (:func:`fit`; its changes kept), or ``None`` when it is not
        applicable (its reasons kept for :meth:`reasons`, not listed: for a run that checks need, listed by
        :meth:`skip` under each check's name)."""
        try:
            fitted = fit(scene, self.backend, allow)
        except Inapplicable as exc:
            self._lacking[run] = exc.reasons
            return None
        if fitted.changes:
            self._adapted.setdefault(fitted.changes, []).append(run)
        return fitted.scene

    def scene(self, name, scene, allow=Allow(), run=None):
        """:meth:`fit`, listing ``name`` (the run and the checks it carries) with its reasons when it is not
        applicable. ``run`` names the run among the adapted ones (default ``name``)."""
        fitted = self.fit(run or name, scene, allow)
        if fitted is None:
            self.skip(name, self.reasons(run or name))
        return fitted

    def skip(self, name, reasons):
        """List ``name`` (a check that needs runs that are not applicable) with ``reasons``."""
        self.not_applicable.append(NotApplicable(name, tuple(dict.fromkeys(reasons))))

    def reasons(self, run):
        """The reasons run ``run`` was found not applicable (empty if it runs)."""
        return self._lacking.get(run, ())

    def record(self):
        """``{"not_applicable": [...], "adapted": [...]}`` for the case's result."""
        return {"not_applicable": list(self.not_applicable),
                "adapted": [Adaptation(tuple(names), changes) for changes, names in self._adapted.items()]}

    def nothing_ran(self):
        """:class:`NothingApplicable` with every item: raise it when no run of the case applies."""
        return NothingApplicable(self.not_applicable)


def require(backend, scenes, allow=Allow()):
    """Raise :class:`NothingApplicable` unless ``backend`` implements every scene of ``scenes`` (``[(name, scene)]``)
    within ``allow``: for a case whose claims need all of them."""
    triage = Triage(backend)
    for name, scene in scenes:
        triage.scene(name, scene, allow)
    if triage.not_applicable:
        raise triage.nothing_ran()

