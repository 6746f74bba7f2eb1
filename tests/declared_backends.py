"""Correct codes that implement a part, unlike the repository's examples: each a delegate of the NumPy reference (so
every stage it has is right) with a declaration of what it implements. ``mpmref verify`` must run on each exactly the
checks its claims allow, never an error (tests/test_verify_declarations.py). Importable by name
(``declared_backends:Sulsky``) when ``tests/`` and ``examples/`` are on the path, as the command-line tests arrange.
"""

import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "examples"))

from mpm88_backend import Mpm88Backend

from mpmref.backends.capabilities import Implements
from mpmref.backends.numpy import NumpyBackend

SYNC_ONLY = {"stepping": ("sync",), "rigid_bodies": False, "colliders": ()}


def declared(name, **declaration):
    """A delegate of the NumPy reference declaring ``declaration`` (an :class:`Implements`, synchronous, no rigid
    bodies or colliders unless given)."""
    return type(name, (NumpyBackend,), {"implements": Implements(**{**SYNC_ONLY, **declaration})})


#: classic MPM as Sulsky et al. 1994 wrote it: 3D, FLIP, the classic force, the linear hat
Sulsky = declared("Sulsky", dims=(3,), schemes=("flip",), forces=("classic",), kernels=("linear",),
                  materials=("neo_hookean",), walls=("sticky",), friction=False, evolves=("F",))
#: 2D PIC with the classic force and the linear hat, one elastic solid, slip walls
Pic2d = declared("Pic2d", dims=(2,), schemes=("pic",), forces=("classic",), kernels=("linear",),
                 materials=("fixed_corotated",), walls=("slip",), friction=False, evolves=("F",))
#: 2D APIC with the MLS force, sand only, sticky and frictional separate walls, a plane collider
Sand2d = declared("Sand2d", dims=(2,), schemes=("apic",), forces=("mls",), kernels=("quadratic",),
                  materials=("sand",), walls=("sticky", "separate"), friction=True, colliders=("plane",),
                  evolves=("C", "F", "Jp"))
#: 3D PolyPIC with the MLS force, one Neo-Hookean solid, sticky walls
Poly3d = declared("Poly3d", dims=(3,), schemes=("polypic",), forces=("mls",), kernels=("quadratic",),
                  materials=("neo_hookean",), walls=("sticky",), friction=False, evolves=("C", "modes", "F"))
#: 3D MLS-MPM with the cubic kernel, one fluid, frictional separate walls
Mls3dFluid = declared("Mls3dFluid", dims=(3,), schemes=("mls",), forces=("mls",), kernels=("cubic",),
                      materials=("fluid",), walls=("separate",), friction=True, evolves=("C", "J"))
#: APIC with the linear hat only: what mpmref cannot model (an affine scheme needs a constant D_p)
ApicLinear = declared("ApicLinear", dims=(2,), schemes=("apic",), forces=("mls",), kernels=("linear",),
                      materials=("fixed_corotated",), walls=("sticky",), friction=False, evolves=("C", "F"))
#: Taichi's mpm99 as a declaration: three materials, snow that never clamps J_P (its bounds fixed far outside any
#: state), sticky walls
Mpm99 = declared("Mpm99", dims=(2,), schemes=("mls",), forces=("mls",), kernels=("quadratic",),
                 materials=("fixed_corotated", "fluid", "snow"),
                 parameters={"snow": {"Jp_min": 1e-300, "Jp_max": 1e300}}, walls=("sticky",), friction=False,
                 evolves=("C", "F", "J", "Jp"))


class Gamma1(Mpm88Backend):
    """The partial example (examples/mpm88_backend.py) declaring the Tait exponent of the 88-line program, γ = 1,
    built in."""

    implements = replace(Mpm88Backend.implements, parameters={"fluid": {"gamma": 1.0}})


class WrongC(NumpyBackend):
    """A complete code whose G2P gives an affine matrix 25 % too large: wrong wherever C matters, invisible where it
    stays at zero (a block in free fall)."""

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        new = super().g2p(particles, v_grid, v_tilde, dt, prepared, kicks)
        return new.with_(C=1.25 * new.C)
