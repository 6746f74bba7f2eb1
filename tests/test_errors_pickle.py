"""Every mpmref error survives pickling, as it must to come back from a worker process."""

import inspect
import pickle

import numpy as np
import pytest

from mpmref import errors

EXAMPLES = {
    "SceneError": ("grid.dx", -1.0, "a number > 0"),
    "ArgumentError": ("steps", -3, "an integer >= 0"),
    "NotImplementedByBackend": ("cuda", "stork2d", ["needs asynchronous time stepping"]),
    "InstabilityError": (12, 7, "v", 0.9),
    "NonFiniteError": (12, 7, "F", 0.9),
    "DomainExitError": (3, [1, 2], np.array([[0.0, 1.5], [2.0, 0.1]])),
    "AllParticlesLeftError": (4, 10),
    "AsyncCensusError": (16, [3], []),
    "TickTooLongError": (1e-3, 5, 1e-4),
    "BackendError": ("backend 'x': unknown",),
    "MpmrefError": ("something",),
}
CLASSES = [c for _, c in inspect.getmembers(errors, inspect.isclass) if issubclass(c, errors.MpmrefError)]


def test_every_error_class_has_an_example():
    assert sorted(c.__name__ for c in CLASSES) == sorted(EXAMPLES)


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_an_error_pickles_with_its_message_and_attributes(cls):
    error = cls(*EXAMPLES[cls.__name__])
    again = pickle.loads(pickle.dumps(error))
    assert type(again) is cls and str(again) == str(error) and repr(again.__dict__) == repr(error.__dict__)
