"""What docs/checking_your_code.md says a backend's stages may read of the scene is what the code has and reads: the
material objects' attributes (every parameter of every material listed, everything the compiled backends read
listed), and the nodes of each wall's band (the reference's bands and the Numba kernel's test, against the ranges
the page gives)."""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from mpmref.backends.numba.grid_update import project_in_bands
from mpmref.backends.numpy.transfers import wall_bands
from mpmref.physics.catalogue import MATERIALS
from mpmref.state import Grid

ROOT = Path(__file__).resolve().parent.parent
PAGE = (ROOT / "docs" / "checking_your_code.md").read_text(encoding="utf-8")
#: the parameters without a default, set to make one material of each type
REQUIRED = {"E": 1.0e4, "K": 1.0e4}


def table_after(header):
    """The rows (lists of cells) of the page's table whose header row is ``header``."""
    lines = PAGE.split(header + "\n", 1)[1].split("\n\n", 1)[0].splitlines()[1:]
    return [[cell.strip() for cell in line.strip("|").split("|")] for line in lines]


def documented_attributes():
    """``{material type: {attribute, ...}}`` as the page's table of material attributes gives them."""
    out = {name: set() for name in MATERIALS}
    for names, materials, _ in table_after("| attribute | materials | meaning |"):
        types = list(MATERIALS) if materials == "all" else re.findall(r"`(\w+)`", materials)
        for material in types:
            out[material] |= set(re.findall(r"`(\w+)`", names))
    return out


def example(material_type):
    cls = MATERIALS[material_type]
    return cls(**{f.name: REQUIRED[f.name] for f in dataclasses.fields(cls) if f.name in REQUIRED})


@pytest.mark.parametrize("material_type", MATERIALS)
def test_every_attribute_the_page_lists_is_on_the_material_and_every_parameter_is_listed(material_type):
    listed = documented_attributes()[material_type]
    material = example(material_type)
    assert listed and all(hasattr(material, name) for name in listed), listed
    assert {f.name for f in dataclasses.fields(material)} <= listed


def test_what_the_compiled_backends_read_of_a_material_is_listed():
    """Both compiled backends read a material through its declared law's parameter row (``compiled.parameters``)."""
    documented = documented_attributes()
    for material_type, cls in MATERIALS.items():
        row = set(cls.compiled.parameters)
        assert row and row <= documented[material_type], (material_type, row - documented[material_type])


def documented_band(cells, width, side):
    """The node indices along an axis of ``cells`` cells that the page's table puts in the band of a face."""
    i = np.arange(cells + 1)
    return (i <= width - 1) if side == "min" else (cells - width + 1 <= i)


@pytest.mark.parametrize("cells", [(8, 12), (9, 8, 14)])
def test_the_reference_bands_are_the_node_ranges_the_page_gives(cells):
    assert "| `x_min`, `y_min`, `z_min` | $0 \\le i_a \\le$ `width` $- 1$ |" in PAGE
    assert "| `x_max`, `y_max`, `z_max` | `cells[a]` $-$ `width` $+ 1 \\le i_a \\le$ `cells[a]` |" in PAGE
    grid = Grid(origin=np.zeros(len(cells)), dx=0.1, cells=cells)
    index = grid.node_indices()
    for width in range(min(cells) // 2):         # 0 .. the largest width a scene accepts
        for name, mask, normal in wall_bands(grid, width):
            axis, side = "xyz".index(name[0]), name[2:]
            assert np.array_equal(mask, documented_band(cells[axis], width, side)[index[:, axis]]), (name, width)
            assert normal[axis] == (1.0 if side == "min" else -1.0)


@pytest.mark.parametrize("cells, width", [(8, 0), (8, 3), (13, 2), (14, 6)])
def test_the_numba_kernels_band_test_covers_the_same_nodes(cells, width):
    """A sticky wall on each side of an axis zeroes the velocity of exactly the nodes of the two bands."""
    sticky, friction = np.ones(2, dtype=np.int64), np.zeros(2)
    covered = np.zeros(cells + 1, dtype=bool)
    for index in range(cells + 1):
        v = np.ones((1, 1))
        project_in_bands.py_func(v, 0, 0, index, cells + 1, width, sticky, friction)
        covered[index] = v[0, 0] == 0.0
    assert np.array_equal(covered, documented_band(cells, width, "min") | documented_band(cells, width, "max"))
