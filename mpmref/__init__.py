"""mpmref: a readable, verified reference of the Material Point Method.

Public API: :class:`Scene`, :class:`SceneBuilder`, :class:`Simulation` and the errors in
:mod:`mpmref.errors`.
"""

from .errors import DomainExitError, MpmrefError, NonFiniteError, SceneError
from .scene import Scene, SceneBuilder
from .simulation import Simulation

__version__ = "0.1.0"
__all__ = ["Scene", "SceneBuilder", "Simulation", "SceneError", "NonFiniteError", "DomainExitError", "MpmrefError"]
