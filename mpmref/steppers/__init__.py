"""Time steppers: how the step size is chosen and how a step is applied."""

from .synchronous import SynchronousStepper

__all__ = ["SynchronousStepper"]
