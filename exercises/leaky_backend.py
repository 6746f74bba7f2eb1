"""A colleague's backend with an energy leak in one of its stages, for exercise 11 of ``docs/exercises.md``.

Treat it as a black box: find the leaking stage and the size of the leak with the energy ledger before you read
the code below.
"""

from mpmref.backends.numpy import NumpyBackend


class LeakyBackend(NumpyBackend):
    """The NumPy reference, but its G2P keeps half of each particle's affine matrix :math:`C_p` (the deformation
    gradient is updated with the whole one)."""

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        new = super().g2p(particles, v_grid, v_tilde, dt, prepared, kicks)
        return new if new.C is None else new.with_(C=0.5 * new.C)
