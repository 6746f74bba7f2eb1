"""Scene factories that the benchmarks and the verification cases share: an example scene with its time settings
varied, and the sand wheel's bodies."""

import tomllib
from pathlib import Path

from ..errors import MpmrefError
from ..rigid.polyline import SAND_WHEEL, wheel
from .builder import Scene

#: the example scenes of a checkout (``examples/``)
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def example_with_time(name, t_end, dt=None, cells=None, interface=None, levels=None, cfl_sync=False):
    """The example ``name`` ending at ``t_end`` (at ``cells`` cells along the first axis if given): as declared
    (asynchronous, with ``time.interface`` = ``interface`` and ``time.levels`` = ``levels`` if given), or
    synchronous with step ``dt``, or with ``cfl_sync`` synchronous at the CFL step of the declared ``time.cfl``."""
    path = EXAMPLES / f"{name}.toml"
    if not path.exists():
        raise MpmrefError(f"this needs {path} (run it from a checkout of mpmref)")
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    declared = data["time"]
    if dt is not None:
        data["time"] = {"dt": dt, "t_end": t_end}
    elif cfl_sync:
        data["time"] = {"cfl": declared["cfl"], "t_end": t_end}
    else:
        data["time"] = {**declared, "t_end": t_end, **({"interface": interface} if interface is not None else {}),
                        **({"levels": levels} if levels is not None else {})}
    data.pop("output", None)
    if cells is not None:
        data["grid"] = {"size": data["grid"]["size"], "cells": cells}
    return Scene.from_dict(data, base_dir=EXAMPLES)


def add_sand_wheel(builder):
    """Add the sand wheel's bodies to a :class:`~mpmref.scene.SceneBuilder`: the ring and the blades welded to it
    (:data:`mpmref.rigid.polyline.SAND_WHEEL`; pinned, shell density 100, angular damping 2.7/s, slip with
    friction 0.4), and a sticky floor segment at y = 0.1."""
    (ring, ring_segments), (blades, blade_segments) = wheel(**SAND_WHEEL)
    turning = {"motion": "dynamic", "density": 100.0, "pinned": True, "angular_damping": 2.7, "type": "slip",
               "friction": 0.4}
    builder.rigid_body(ring, ring_segments, **turning).rigid_body(blades, blade_segments, welded_to=0, **turning)
    return builder.rigid_body([[0.03, 0.1], [0.97, 0.1]], [[0, 1]], motion="fixed", type="sticky")
