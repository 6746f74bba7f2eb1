"""Execution backends: the built-in ones, installed plugins and a user's own, each named by a *backend reference*.

Everywhere a backend is asked for (``Simulation(scene, backend=...)``, ``--backend`` of the command line, the
conformance harness, the verification cases, ``mpmref study``), it may be given as

* a built-in name of :data:`BUILTIN`: ``"numpy"`` (the reference), ``"numba"`` or ``"cuda"`` (a GPU,
  docs/gpu.md);
* the name of an installed plugin: an entry point of the group :data:`ENTRY_POINT_GROUP` (``mpmref.backends``)
  whose object is a factory, declared in the plugin's ``pyproject.toml`` as
  ``[project.entry-points."mpmref.backends"] mine = "my_package.backend:factory"``;
* ``"MODULE:ATTRIBUTE"``: a factory that ``import MODULE`` makes available (``ATTRIBUTE`` may be dotted);
* in Python, a factory itself, ``factory(scene) -> backend`` (a backend class is one), or a backend object
  already made for the scene.

Strings are what travel to worker processes (the verification cases run their sweeps there), so a reference
given on the command line is resolved again in each worker. Whatever the form, :func:`make_backend` checks the
backend against its scene before any work: every stage the scene needs (:func:`.base.required_calls`) must be
there and accept the arguments the steppers pass, and a missing one is named with its expected signature.
"""

import importlib
import sys
from functools import lru_cache
from importlib.metadata import entry_points
from pathlib import Path

from ..errors import BackendError, NotImplementedByBackend
from .capabilities import declared, declined

#: the built-in backends that run on every machine (the tests and benchmarks run each by default)
BACKENDS = ("numpy", "numba")
#: the built-in backends that need a device: ``cuda``, numba-cuda on a GPU (docs/gpu.md; the extra ``[gpu]``)
DEVICE_BACKENDS = ("cuda",)
#: every built-in backend name
BUILTIN = BACKENDS + DEVICE_BACKENDS
#: the entry-point group through which an installed package registers a backend by name
ENTRY_POINT_GROUP = "mpmref.backends"


def plugin_names():
    """Names of the backends that installed packages register (entry points of :data:`ENTRY_POINT_GROUP`)."""
    return sorted(e.name for e in entry_points(group=ENTRY_POINT_GROUP) if e.name not in BUILTIN)


def available():
    """Every backend name: the built-in ones, then the installed plugins'."""
    return list(BUILTIN) + plugin_names()


def _builtin(name):
    if name == "numpy":
        from .numpy import NumpyBackend

        return NumpyBackend
    if name == "cuda":
        from .cuda import CudaBackend

        return CudaBackend
    from .numba import NumbaBackend

    return NumbaBackend


def _unknown(reference):
    plugins = plugin_names()
    installed = f"; installed plugins: {', '.join(plugins)}" if plugins else ""
    return BackendError(f"unknown backend {reference!r}: the built-in backends are {', '.join(BUILTIN)}{installed}; "
                        "or give your own as MODULE:ATTRIBUTE (a factory f(scene) -> backend, e.g. a backend class)")


def _import_attribute(reference):
    """The object ``MODULE:ATTRIBUTE`` names; :class:`BackendError` naming the module or the attribute."""
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise BackendError(f"backend {reference!r}: expected MODULE:ATTRIBUTE, e.g. my_backend:MyBackend")
    try:
        obj = importlib.import_module(module_name)
    except ImportError as exc:
        raise BackendError(f"backend {reference!r}: cannot import module {module_name!r} ({exc}); it must be "
                           "importable from this Python (installed, on PYTHONPATH or in the current folder)") from None
    for part in attribute.split("."):
        if not hasattr(obj, part):
            raise BackendError(f"backend {reference!r}: module {module_name!r} has no attribute {attribute!r}")
        obj = getattr(obj, part)
    return obj


def _load_plugin(name):
    entry = next(e for e in entry_points(group=ENTRY_POINT_GROUP) if e.name == name)
    try:
        return entry.load()
    except (ImportError, AttributeError) as exc:
        raise BackendError(f"backend {name!r}: the plugin's entry point {entry.value!r} cannot be loaded "
                           f"({exc})") from None


def resolve(reference):
    """The factory or backend object that ``reference`` names (see the module docstring); strings are looked up
    as a built-in name, a plugin name, then ``MODULE:ATTRIBUTE``. :class:`BackendError` if none fits."""
    if not isinstance(reference, str):
        return reference
    if reference in BUILTIN:
        return _builtin(reference)
    if ":" in reference:
        return _import_attribute(reference)
    if reference in plugin_names():
        return _load_plugin(reference)
    raise _unknown(reference)


def label(reference):
    """How ``reference`` is named in reports and messages: the string itself, else the factory's or the object's
    qualified name."""
    if isinstance(reference, str):
        return reference
    named = reference if callable(reference) and not _is_backend_object(reference) else type(reference)
    return f"{named.__module__}:{named.__qualname__}"


def _is_backend_object(obj):
    """A backend object (not a class or factory function): it has a ``p2g`` method and is not a class."""
    return not isinstance(obj, type) and callable(getattr(obj, "p2g", None))


def make_backend(reference, scene):
    """The backend that ``reference`` names, for ``scene``, checked against what the scene needs.

    Parameters
    ----------
    reference : str, callable or backend object
        See the module docstring.
    scene : Scene

    Returns
    -------
    A backend with every stage of :func:`.base.required_calls` ``(scene)``; :class:`BackendError` otherwise (also
    for an unknown name, a module or attribute that cannot be imported, and an object made for another scene).
    """
    found = resolve(reference)
    refuse_unimplemented(found, label(reference), scene)
    if _is_backend_object(found):
        backend = found
        made_for = getattr(backend, "scene", None)
        if made_for is not None and made_for is not scene and made_for.fingerprint() != scene.fingerprint():
            raise BackendError(f"backend {label(reference)}: this object was made for another scene "
                               f"({made_for.name!r}); give a factory f(scene) -> backend instead")
    elif callable(found):
        try:
            backend = found(scene)
        except NotImplementedError as exc:
            raise NotImplementedByBackend(label(reference), scene.name, [declined(exc)]) from None
    else:
        raise BackendError(f"backend {label(reference)}: a {type(found).__name__} is neither a factory "
                           "f(scene) -> backend nor a backend object")
    return checked(backend, label(reference), scene)


def implements(reference, scenes=None):
    """What the backend ``reference`` names declares it implements (:class:`.capabilities.Implements`; everything
    if it declares nothing). A factory function that declares nothing itself is asked through the object it makes for
    the first of ``scenes`` (default: :func:`.capabilities.probe_scenes`) it can make (:func:`.capabilities.probed`),
    so a declaration on the backend's class is enough."""
    from .capabilities import probe_scenes, probed

    return probed(resolve(reference), probe_scenes() if scenes is None else scenes)


def refuse_unimplemented(found, name, scene):
    """:class:`~mpmref.errors.NotImplementedByBackend` if the backend, class or factory ``found`` declares that it
    does not implement something ``scene`` needs (:meth:`.capabilities.Implements.missing`)."""
    reasons = declared(found).missing(scene)
    if reasons:
        raise NotImplementedByBackend(name, scene.name, reasons)


def checked(backend, name, scene=None):
    """``backend`` if it has every stage ``scene`` (default: its own ``scene``) needs, each accepting the
    arguments the steppers pass (:func:`.base.required_calls`); :class:`BackendError` naming each missing or
    incompatible stage with its expected signature otherwise: :class:`~mpmref.errors.NotImplementedByBackend` when
    what is missing is only what some scenes need (its declaration, the stages of asynchronous stepping or CPIC)."""
    from .base import BACKEND_STAGES, required_calls, stage_signature

    scene = scene if scene is not None else backend.scene
    refuse_unimplemented(backend, name, scene)
    problems, optional = [], []
    for stage, (positional, keywords) in required_calls(scene).items():
        method = getattr(backend, stage, None)
        every_scene = stage in BACKEND_STAGES + ("running",) and not keywords
        if not callable(method):
            (problems if every_scene else optional).append(f"lacks the stage {stage_signature(stage)}")
        elif not _accepts(method, positional, keywords):
            (problems if every_scene else optional).append(
                f"has a stage {stage} that does not accept the steppers' {positional} positional argument(s)"
                f"{' and ' + ', '.join(keywords) if keywords else ''}: expected {stage_signature(stage)}")
    if problems:
        raise BackendError(f"backend {name!r} {'; '.join(problems + optional)} (needed by scene {scene.name!r}; the "
                           "contract: mpmref.backends.base, docs/checking_your_code.md)")
    if optional:  # stages only asynchronous or CPIC scenes need: the backend does not implement those
        raise NotImplementedByBackend(name, scene.name, optional)
    return backend


def _accepts(method, positional, keywords):
    """Whether ``method`` can be called with ``positional`` arguments and the keyword arguments ``keywords``. A bound
    method is judged by its function, which takes the instance first, once per function (:data:`_function_binds`):
    every case of a conformance check makes a backend and checks its stages."""
    function = getattr(method, "__func__", None)
    if function is not None and getattr(method, "__self__", None) is not None:
        return _function_binds(function, positional + 1, tuple(keywords))
    return _binds(method, positional, keywords)


def _binds(function, positional, keywords):
    """Whether ``function`` can be called with ``positional`` arguments and the keyword arguments ``keywords``."""
    import inspect

    try:
        signature = inspect.signature(function)
    except (TypeError, ValueError):  # a builtin without a signature: nothing to check
        return True
    try:
        signature.bind(*range(positional), **{k: None for k in keywords})
    except TypeError:
        return False
    return True


#: :func:`_binds` once per function of a bound method
_function_binds = lru_cache(maxsize=1024)(_binds)


def describe(reference, backend):
    """``{"backend": label, "class": ..., "version": ..., "execution": ...}`` of the backend ``reference`` named, as
    made, for reports: the backend's ``version`` attribute if it has one, else the version of the installed
    distribution that provides its module (mpmref's own for the built-in backends), else that module's
    ``__version__``, else ``None``; and what its optional ``describe_execution()`` says of how it runs (the Numba
    backend: its threads), else ``None``."""
    cls = type(backend)
    module = cls.__module__.split(".")[0]
    version = getattr(backend, "version", None)
    if version is None:
        version = _distribution_version(module)
    execution = getattr(backend, "describe_execution", None)
    return {"backend": label(reference), "class": f"{cls.__module__}.{cls.__qualname__}",
            "version": None if version is None else str(version),
            "execution": execution() if callable(execution) else None}


@lru_cache(maxsize=None)
def _distribution_version(module):
    from importlib.metadata import PackageNotFoundError, packages_distributions, version

    for distribution in packages_distributions().get(module, []):
        try:
            return version(distribution)
        except PackageNotFoundError:
            continue
    return getattr(sys.modules.get(module), "__version__", None)


def importable_from_here():
    """Put the current folder on ``sys.path`` (as ``python -m`` does) so that ``--backend MODULE:ATTRIBUTE`` finds
    a module beside the user's scene; the command line calls this once before resolving a reference."""
    here = str(Path.cwd())
    if here not in sys.path and "" not in sys.path:
        sys.path.insert(0, here)


#: the help of every ``--backend`` option
OPTION_HELP = ("the backend: numpy (the reference), numba, cuda (a GPU), an installed plugin's name, or your own as "
               "MODULE:ATTRIBUTE, a factory f(scene) -> backend (docs/checking_your_code.md)")


def reference_argument(text):
    """The argparse ``type`` of every ``--backend`` option (and of each of ``bench --backends``): ``text`` itself,
    once it resolves (:func:`resolve`; a ``MODULE:ATTRIBUTE`` may name a module in the current folder) and, for the
    GPU backend, once a GPU is usable (:func:`refuse_missing_device`). Otherwise :class:`BackendError`, which the
    command line reports in one line with exit status 2 before any work."""
    if ":" in text:
        importable_from_here()
    refuse_missing_device(resolve(text))
    return text


def refuse_missing_device(found):
    """:class:`BackendError` in one line naming what is missing (numba-cuda, or a CUDA GPU with its driver:
    :func:`.cuda.runtime.require_device`, the check that making the backend does) when ``found``, a resolved
    reference, is the GPU backend or one of its factories (``cuda``, ``mpmref.backends.cuda:atomic``)."""
    if getattr(found, "__module__", "").startswith(f"{__name__}.cuda"):
        from .cuda.runtime import require_device

        require_device()
