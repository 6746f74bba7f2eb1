"""One test per class of bad scene: each error names the field, the value and the allowed range."""

import copy

import pytest
from helpers import box_scene

from mpmref import Scene, SceneBuilder, SceneError
from mpmref.scene.sampling import sample_particles


def good():
    return (SceneBuilder(dim=2, name="ok").grid(size=1.0, cells=16).method("apic")
            .material("jelly", "fixed_corotated", E=1e3, nu=0.3, rho=1.0)
            .box("jelly", lower=[0.3, 0.3], upper=[0.6, 0.6]).time(dt=1e-4, steps=10).as_dict())


def with_(path, value):
    d = copy.deepcopy(good())
    *head, last = path
    target = d
    for k in head:
        target = target[k]
    if value is _DELETE:
        del target[last]
    else:
        target[last] = value
    return d


_DELETE = object()


def check_refused(data, field, allowed_words):
    with pytest.raises(SceneError) as info:
        sample_particles(Scene.from_dict(data))
    err = info.value
    assert err.field == field
    assert allowed_words in err.allowed
    assert field in str(err)
    return err


def test_the_good_scene_is_accepted():
    scene = Scene.from_dict(good())
    assert sample_particles(scene).n > 0


def test_unknown_top_level_key():
    check_refused(with_(["gravty"], [0, -9.8]), "gravty", "known keys")


def test_unknown_nested_key():
    check_refused(with_(["materials", "jelly", "youngs"], 1.0), "materials.jelly.youngs", "known keys")


def test_missing_required_field():
    check_refused(with_(["materials", "jelly", "E"], _DELETE), "materials.jelly.E", "required")


def test_wrong_type():
    err = check_refused(with_(["materials", "jelly", "E"], "stiff"), "materials.jelly.E", "finite number")
    assert err.value == "stiff"


@pytest.mark.parametrize("nu", [0.5, 0.7, -0.1])
def test_poisson_ratio_out_of_range(nu):
    err = check_refused(with_(["materials", "jelly", "nu"], nu), "materials.jelly.nu", "[0.0, 0.5)")
    assert err.value == nu


@pytest.mark.parametrize("E", [0.0, -5.0])
def test_youngs_modulus_must_be_positive(E):
    check_refused(with_(["materials", "jelly", "E"], E), "materials.jelly.E", "(0.0, inf]")


@pytest.mark.parametrize("dx", [0.0, -0.1])
def test_grid_spacing_must_be_positive(dx):
    d = good()
    d["grid"] = {"size": [1.0, 1.0], "dx": dx}
    check_refused(d, "grid.dx", "(0.0, inf]")


def test_grid_size_must_be_whole_cells():
    d = good()
    d["grid"] = {"size": [1.0, 1.0], "dx": 0.3}
    check_refused(d, "grid.size", "whole number")


def test_non_finite_value():
    check_refused(with_(["time", "dt"], float("nan")), "time.dt", "finite number")


def test_unknown_choice():
    check_refused(with_(["method", "scheme"], "sph"), "method.scheme", "'pic'")


def test_flip_alpha_only_with_flip():
    d = with_(["method", "flip_alpha"], 0.9)
    check_refused(d, "method.flip_alpha", "only with method.scheme = 'flip'")


def test_dt_and_cfl_are_exclusive():
    check_refused(with_(["time", "cfl"], 0.5), "time.dt", "exactly one")


def test_body_outside_domain_names_body_and_region():
    d = good()
    d["bodies"][0]["upper"] = [1.2, 0.6]
    err = check_refused(d, "bodies[0]", "valid region")
    assert "quadratic" in err.allowed


def test_body_refers_to_unknown_material():
    check_refused(with_(["bodies", 0, "material"], "steel"), "bodies[0].material", "'jelly'")


def test_disk_in_3d_is_refused():
    d = good()
    d.update(dim=3, grid={"size": 1.0, "cells": 16})
    d["bodies"] = [{"shape": "disk", "material": "jelly", "center": [0.5] * 3, "radius": 0.1}]
    check_refused(d, "bodies[0].shape", "'sphere' in a 3D scene")


def test_regular_sampling_needs_perfect_power():
    check_refused(with_(["bodies", 0, "ppc"], 3), "bodies[0].ppc", "perfect square")


def test_vector_of_wrong_length():
    check_refused(with_(["gravity"], [0.0, -9.8, 0.0]), "gravity", "list of 2")


def test_wall_type_and_friction():
    d = good()
    d["boundary"] = {"walls": {"y_min": {"type": "glue"}}}
    check_refused(d, "boundary.walls.y_min.type", "'sticky'")
    d["boundary"] = {"walls": {"y_min": {"friction": -0.1}}}
    check_refused(d, "boundary.walls.y_min.friction", "[0.0, inf]")


def test_invalid_toml_file(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("dim = 2\n[grid\nsize = 1\n")
    with pytest.raises(SceneError) as info:
        Scene.from_toml(path)
    assert info.value.field == "scene file" and "valid TOML" in info.value.allowed


def test_missing_scene_file(tmp_path, monkeypatch):
    """The message says the file does not exist and names it (a relative path also as it resolved); the error still
    names the field and what is allowed, as every scene error does."""
    with pytest.raises(SceneError) as info:
        Scene.from_toml(tmp_path / "nope.toml")
    assert str(info.value) == f"scene file '{tmp_path / 'nope.toml'}' does not exist"
    assert info.value.field == "scene file" and info.value.allowed == "an existing TOML file"
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SceneError, match=r"^scene file 'nope.toml' does not exist \(no such file: .*nope.toml\)$"):
        Scene.from_toml("nope.toml")
    with pytest.raises(SceneError, match="is a folder, not a TOML file"):
        Scene.from_toml(tmp_path)


def test_toml_key_after_bodies_table_is_reported_as_body_key(tmp_path):
    """A common TOML slip: a top-level key written after [[bodies]] belongs to the body."""
    path = tmp_path / "slip.toml"
    path.write_text(
        'dim = 2\n[grid]\nsize = 1.0\ncells = 16\n[materials.m]\ntype = "fluid"\nK = 10.0\n'
        '[[bodies]]\nshape = "box"\nmaterial = "m"\nlower = [0.3, 0.3]\nupper = [0.6, 0.6]\n'
        'gravity = [0.0, -9.8]\n[time]\ndt = 1e-4\n'
    )
    with pytest.raises(SceneError) as info:
        Scene.from_toml(path)
    assert info.value.field == "bodies[0].gravity"


def test_python_builder_and_dict_agree():
    a = box_scene(2, "apic")
    b = Scene.from_dict(SceneBuilder(dim=2, name="t").grid(size=1.0, cells=16)
                        .method("apic", kernel="quadratic", force="mls")
                        .material("m", "fixed_corotated", E=1e3, nu=0.3, rho=1.0)
                        .box("m", lower=[0.3] * 2, upper=[0.7] * 2, ppc=4).walls("open")
                        .time(dt=1e-4, steps=10).as_dict())
    assert a.fingerprint() == b.fingerprint()


# ---- combination rules of scheme, force and kernel (one test per rule)
def method_scene(**method):
    d = good()
    d["method"] = method
    return d


def test_mls_scheme_with_classic_force_is_refused_naming_both():
    err = check_refused(method_scene(scheme="mls", force="classic"), "method.force", "method.scheme = 'mls'")
    assert "classic" in str(err)


@pytest.mark.parametrize("scheme", ["apic", "polypic", "mls"])
def test_linear_kernel_with_affine_scheme_is_refused_naming_both(scheme):
    err = check_refused(method_scene(scheme=scheme, kernel="linear", force="classic" if scheme != "mls" else "mls"),
                 "method.kernel", f"method.scheme = '{scheme}'")
    assert "linear" in str(err)


def test_linear_kernel_with_mls_force_is_refused_naming_both():
    err = check_refused(method_scene(scheme="pic", kernel="linear"), "method.force", "method.kernel = 'linear'")
    assert "'mls'" in str(err)
