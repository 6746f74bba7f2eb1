"""Scenes too large for this machine, and files that are not scenes, are refused before any allocation."""

import pytest

from mpmref import Scene, SceneBuilder, SceneError
from mpmref.scene import memory_limits
from mpmref.scene.sampling import sample_particles

GIB = 2**30


@pytest.fixture
def one_gib(monkeypatch):
    """Pretend this machine has 1 GiB available, so the limit (half of it) is 512 MiB."""
    monkeypatch.setattr(memory_limits, "available_memory", lambda: (GIB, "a test figure"))
    return GIB // 2


def scene(dim=2, body=None, upper=0.6, **grid):
    b = (SceneBuilder(dim=dim).grid(**(grid or {"size": 1.0, "cells": 16}))
         .material("m", "fixed_corotated", E=1e3).time(dt=1e-4, steps=1))
    return b.box("m", lower=[0.3] * dim, upper=[upper] * dim, **(body or {}))


def test_a_tiny_dx_is_refused_with_estimate_and_limit(one_gib):
    with pytest.raises(SceneError) as info:
        scene(size=1.0, dx=1e-6).build()
    err = info.value
    assert err.field == "grid.dx" and err.value == 1e-6
    assert "nodes need about 87.3 TiB" in err.allowed and "512 MiB" in err.allowed and "a test figure" in err.allowed


def test_an_absurd_dx_is_refused_per_axis_before_rounding(one_gib):
    with pytest.raises(SceneError) as info:
        scene(size=1.0, dx=1e-300).build()
    assert info.value.field == "grid.dx" and "cells along any axis in 2D" in info.value.allowed


def test_cells_per_axis_bound_depends_on_the_dimension(one_gib):
    scene(2, size=1.0, cells=2048, upper=0.31).build()  # 2049² nodes x 96 B = 384 MiB
    with pytest.raises(SceneError) as info:
        scene(3, size=1.0, cells=2048).build()  # 2049³ nodes x 136 B = 1.1 TiB
    assert info.value.field == "grid.cells" and info.value.value == 2048 and "3D" in info.value.allowed


def test_grid_that_fits_is_accepted_and_one_node_more_per_axis_is_not(one_gib):
    per_node = memory_limits.bytes_per_node(3)
    n = int((one_gib // per_node) ** (1 / 3))  # nodes per axis that fit
    scene(3, size=1.0, cells=n - 1, upper=0.31).build()
    with pytest.raises(SceneError) as info:
        scene(3, size=1.0, cells=n + 1, upper=0.31).build()
    assert info.value.field == "grid.cells" and f"{(n + 2) ** 3:,} nodes" in info.value.allowed


def test_too_many_random_particles_name_the_count(one_gib):
    with pytest.raises(SceneError) as info:
        scene(body={"sampling": "random", "count": 10**10}).build()
    err = info.value
    assert err.field == "bodies[0].count" and err.value == 10**10
    assert "10,000,000,000 particles" in err.allowed and "at most" in err.allowed


def test_too_many_particles_per_cell_name_the_ppc(one_gib):
    with pytest.raises(SceneError) as info:
        scene(3, size=1.0, cells=128, body={"ppc": 64}).build()
    assert info.value.field == "bodies[0].ppc" and info.value.value == 64


def test_the_particle_estimate_bounds_the_sampled_count():
    for body in ({"ppc": 4}, {"ppc": 4, "sampling": "jittered"}, {"sampling": "random", "count": 77}):
        s = scene(body=body).build()
        estimate = memory_limits.estimated_particles(s.bodies[0], 2, s.grid.dx)
        assert sample_particles(s).n <= estimate <= 1.5 * sample_particles(s).n + 16


def test_available_memory_reads_meminfo_or_falls_back(monkeypatch):
    available, source = memory_limits.available_memory()
    assert available > 0 and source
    def fail(*args, **kwargs):
        raise OSError("not on this machine")

    monkeypatch.setattr(memory_limits, "open", fail, raising=False)
    from_sysconf = memory_limits.available_memory()
    assert from_sysconf[0] > 0 and "os.sysconf" in from_sysconf[1]
    monkeypatch.setattr(memory_limits.os, "sysconf", fail)
    fallback, source = memory_limits.available_memory()
    assert fallback == memory_limits.FALLBACK_AVAILABLE and "assumed 4 GiB" in source


@pytest.mark.parametrize("content, expected", [
    ("dim = 2\n".encode("utf-16"), "UTF-16"),
    (bytes(range(256)), "NUL"),
    ('name = "café"\n'.encode("latin-1"), "byte 11 is not UTF-8"),
    (b"dim = \n", "valid TOML"),
])
def test_files_that_are_not_utf8_toml_are_scene_errors(tmp_path, content, expected):
    path = tmp_path / "s.toml"
    path.write_bytes(content)
    with pytest.raises(SceneError) as info:
        Scene.from_toml(path)
    assert info.value.field == "scene file" and expected in info.value.allowed


def test_a_directory_is_not_a_scene(tmp_path):
    with pytest.raises(SceneError, match="is a folder, not a TOML file"):
        Scene.from_toml(tmp_path)
