r"""Two processes compile a first run's serial builds: this one from the first stage of a step on, a helper from the
last stage back.

A first run compiles its kernels one after the other, in the order a step calls them, on one core
(:mod:`mpmref.run.first_run`); on a machine with a second core, that core has waited for the parallel builds, which
compile only after the serial ones. So the helper process that compiles the parallel builds starts as soon as this
process has its first kernel to compile, and first helps with the serial builds: it runs the scene's warm-up step
without running the kernels (:class:`Recorder`: a kernel's argument types are all that Numba compiles for), then
compiles the serial builds of the recorded kernels from the last one back (:func:`compile_recorded`), while this
process compiles them from the first one on (:class:`Leader`). The two meet in the middle of the step.

A build is compiled by one of the two: each *claims* it before compiling it, by creating a file named by Numba's own
cache key of the build (the function's code, its closure constants and the argument types; :func:`claim_key`) in a
folder both know (:class:`Claims`); the helper skips what this process has claimed, and this process waits for what the
helper has claimed, then loads it from Numba's disk cache, where the helper put it. If the helper ends before it has
compiled what it claimed, this process compiles it. Nothing depends on the helper: the same builds are compiled, by
one process or the other, and a build is the same bits whoever compiled it.

The helper's step runs none of the kernels whose results are written in place; a kernel that returns a value (the
block keys of the sort) runs, since what follows reads it. What the skipped kernels would have written is left as it
was, and read only by other kernels (skipped too) until the step ends; the helper records only the backend's
warm-up step, not an asynchronous stepper's bookkeeping, which reads the kernels' results.
"""

import ast
import contextlib
import hashlib
import inspect
import os
import textwrap
import time
from functools import lru_cache

from . import twin

#: how often this process looks whether the helper has compiled what it waits for [s]
POLL_S = 0.005


def claim_key(dispatcher, signature):
    """The name of ``dispatcher``'s build for the argument types ``signature``: a hash of Numba's disk-cache index
    name and index key for it (the same in every process that compiles the same function for the same types)."""
    cache = dispatcher._cache
    index_key = cache._index_key(signature, dispatcher.targetctx.codegen())
    return hashlib.sha256(repr((cache._cache_file._index_name, index_key)).encode()).hexdigest()


class Claims:
    """The claims of two processes on the builds they compile, as files in ``folder``: ``KEY`` claimed, ``KEY.done``
    no longer compiling (compiled and in Numba's disk cache, or failed)."""

    def __init__(self, folder):
        self.folder = folder

    def take(self, key):
        """Claim the build ``key``; whether this call claimed it (``False``: claimed before, or the folder is gone)."""
        try:
            os.close(os.open(os.path.join(self.folder, key), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except OSError:
            return False
        return True

    def finish(self, key):
        """Say that the build ``key`` is no longer being compiled."""
        try:
            os.close(os.open(os.path.join(self.folder, key + ".done"), os.O_CREAT | os.O_WRONLY))
        except OSError:
            pass

    def finished(self, key):
        """Whether the build ``key`` is no longer being compiled."""
        return os.path.exists(os.path.join(self.folder, key + ".done"))


class Leader:
    """This process's side: a kernel's build is compiled here unless the helper has claimed it, in which case this
    process waits until the helper has cached it (or has ended) and loads it. ``start()`` starts the helper and
    returns it (an object with ``alive()`` and the two processes' ``claims``, :class:`Claims`); it is called at the
    first build this process has to compile."""

    def __init__(self, start):
        self._start, self.helper = start, None

    def admit(self, kernel, build, args):
        """Before ``build`` of ``kernel`` runs on ``args``: compile nothing here that the helper compiles. Always runs
        the build (returns ``True``)."""
        signature = twin.signature_of(build, args)
        if twin.cached_build(build, signature):
            return True
        if self.helper is None:
            self.helper = self._start()
        key, claims = claim_key(build, signature), self.helper.claims
        if not claims.take(key):
            while not claims.finished(key) and self.helper.alive():
                time.sleep(POLL_S)
        return True


class Recorder:
    """The helper's side: records the kernels a step calls and the types of their arguments, in order, and skips
    them, but for those that return a value (:func:`returns_value`), which run."""

    def __init__(self):
        #: ``(kernel, argument types)`` of each skipped call, in order, each once
        self.calls = []

    def admit(self, kernel, build, args):
        """Record the call and skip it, or run it if the kernel returns a value."""
        if returns_value(kernel.py_func):
            return True
        call = (kernel, twin.signature_of(kernel.serial, args))
        if call not in self.calls:
            self.calls.append(call)
        return False


@lru_cache(maxsize=None)
def returns_value(function):
    """Whether ``function``'s source has a ``return`` with a value."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(function)))
    return any(isinstance(node, ast.Return) and node.value is not None for node in ast.walk(tree))


def compile_recorded(calls, claims):
    """Compile the serial builds of the recorded ``calls`` from the last one back, each unless the other process has
    claimed it; then their parallel builds, in order. Each goes to Numba's disk cache as it is compiled."""
    for kernel, signature in reversed(calls):
        key = claim_key(kernel.serial, signature)
        if claims.take(key):
            with contextlib.suppress(Exception):  # a build that fails here fails in the run too, which says why
                kernel.serial.compile(signature)
            claims.finish(key)  # compiled, or failed: the other process waits no longer
    for kernel, signature in calls:
        kernel.parallel.compile(signature)
