"""Fuzz of ``mpmref run`` (hypothesis, seeded by the conftest profile): malformed scenes, bad bytes and bad
flags all exit with status 2, one message naming the field or option, no traceback and no output written."""

import contextlib
import io
import math
import tempfile
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from mpmref.cli import main

NAN, INF = float("nan"), float("inf")


def good_scene():
    return {
        "dim": 2, "name": "fuzz",
        "grid": {"size": [1.0, 1.0], "cells": 16},
        "method": {"scheme": "apic", "force": "mls"},
        "materials": {"jelly": {"type": "fixed_corotated", "E": 1e3, "nu": 0.3, "rho": 1.0}},
        "bodies": [{"shape": "box", "material": "jelly", "lower": [0.3, 0.3], "upper": [0.6, 0.6], "ppc": 4}],
        "boundary": {"type": "separate", "friction": 0.2, "width": 2, "domain_exit": "error"},
        "time": {"dt": 1e-4, "steps": 2},
        "output": {"every": 1},
    }


NOT_A_NUMBER = ["abc", True, ["x"], {"k": 1}]
NOT_A_VECTOR = ["abc", True, [1.0], [1.0, 2.0, 3.0], ["a", "b"], [NAN, 0.5], [0.5, INF]]
#: (path, values that are invalid there); the error must name the path
BAD_FIELDS = {
    ("dim",): [0, 1, 4, 2.0, "2", True],
    ("grid", "size"): NOT_A_VECTOR + [[-1.0, 1.0], [0.0, 1.0]],
    ("grid", "cells"): NOT_A_NUMBER + [0, 3, -16, 10**9, 16.5],
    ("grid", "origin"): NOT_A_VECTOR,
    ("method", "scheme"): ["nope", 3, ""],
    ("method", "kernel"): ["sinc", 2],
    ("materials", "jelly", "E"): NOT_A_NUMBER + [0.0, -1.0, NAN, INF, -INF],
    ("materials", "jelly", "nu"): NOT_A_NUMBER + [0.5, -0.1, 1e300, NAN],
    ("materials", "jelly", "rho"): NOT_A_NUMBER + [0.0, -5.0, INF],
    ("bodies", 0, "ppc"): NOT_A_NUMBER + [0, 65, 5, 10**12],
    ("bodies", 0, "lower"): NOT_A_VECTOR,
    ("bodies", 0, "upper"): NOT_A_VECTOR + [[0.1, 0.1]],
    ("bodies", 0, "material"): ["steel", 1],
    ("bodies", 0, "velocity"): NOT_A_VECTOR,
    ("boundary", "width"): NOT_A_NUMBER + [-1, 100],
    ("boundary", "friction"): NOT_A_NUMBER + [-0.5, NAN],
    ("boundary", "domain_exit"): ["bounce", 0],
    ("time", "dt"): NOT_A_NUMBER + [0.0, -1e-4, NAN, INF],
    ("time", "steps"): NOT_A_NUMBER + [-1, 2.5],
    ("output", "every"): NOT_A_NUMBER + [0, -3],
}
SECTIONS = [(), ("grid",), ("method",), ("materials", "jelly"), ("bodies", 0), ("boundary",), ("time",), ("output",)]


# ----------------------------------------------------------------------------------- TOML writer
def toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}"


def toml_table(header, table):
    lines = [f"[{header}]"] if header else []
    lines += [f"{k} = {toml_value(v)}" for k, v in table.items() if not isinstance(v, dict) or not v]
    for k, v in table.items():
        if isinstance(v, dict) and v:
            lines.append(toml_table(f"{header}.{k}" if header else k, v))
    return "\n".join(lines)


def to_toml(scene):
    scalars = {k: v for k, v in scene.items() if k != "bodies"}
    text = toml_table("", scalars)
    for body in scene.get("bodies", []):
        text += "\n[[bodies]]\n" + "\n".join(f"{k} = {toml_value(v)}" for k, v in body.items())
    return text + "\n"


# --------------------------------------------------------------------------------------- running
def run_cli(scene_bytes, *flags):
    """Run ``mpmref run`` in this process on a scene file; returns (status, stderr, whether --out exists)."""
    with tempfile.TemporaryDirectory() as tmp:
        path, out = Path(tmp) / "scene.toml", Path(tmp) / "out"
        path.write_bytes(scene_bytes)
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            status = main(["run", str(path), "--out", str(out), "--no-progress", *flags])
        return status, err.getvalue(), out.exists()


def assert_refused(status, err, out_written, named):
    assert status == 2, err
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert named in err, f"{named!r} not named in: {err}"
    assert not out_written


def set_path(data, path, value):
    target = data
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value


def dotted(path):
    text = ""
    for key in path:
        text += f"[{key}]" if isinstance(key, int) else (f".{key}" if text else key)
    return text


@given(st.sampled_from(sorted(BAD_FIELDS, key=str)).flatmap(
    lambda path: st.tuples(st.just(path), st.sampled_from(BAD_FIELDS[path]))))
def test_a_malformed_field_exits_2_naming_it(case):
    path, value = case
    scene = good_scene()
    set_path(scene, path, value)
    assert_refused(*run_cli(to_toml(scene).encode()), named=dotted(path))


@given(st.sampled_from(SECTIONS), st.from_regex(r"[a-z][a-z_]{2,12}", fullmatch=True))
def test_an_unknown_key_exits_2_naming_it(section, key):
    scene = good_scene()
    target = scene
    for k in section:
        target = target[k]
    if key in target or (section == ("materials", "jelly") and key == "type"):
        return
    target[key] = 1
    assert_refused(*run_cli(to_toml(scene).encode()), named=key)


@given(st.one_of(st.tuples(st.just(("bodies", 0, "count")), st.integers(10**10, 10**18)),
                 st.tuples(st.just(("grid", "dx")), st.integers(20, 1000).map(lambda k: 2.0**-k))))  # whole cells
def test_a_huge_scene_exits_2_naming_the_field_before_allocating(case):
    path, size = case
    scene = good_scene()
    if path[-1] == "count":
        scene["bodies"][0].update(sampling="random", count=size)
    else:
        del scene["grid"]["cells"]
        scene["grid"]["dx"] = size
    assert_refused(*run_cli(to_toml(scene).encode()), named=dotted(path))


@given(st.one_of(st.binary(max_size=200).map(lambda b: b"\xff" + b),
                 st.binary(max_size=200).map(lambda b: b + b"\x00"),
                 st.sampled_from(["utf-16", "utf-16-le", "utf-32"]).map(lambda enc: to_toml(good_scene()).encode(enc))))
def test_bad_bytes_exit_2_naming_the_scene_file(content):
    assert_refused(*run_cli(content), named="scene file")


@given(st.one_of(
    st.tuples(st.just("--steps"), st.one_of(st.integers(max_value=-1).map(str),
                                            st.sampled_from(["x", "1.5", "1e3", ""]))),
    st.tuples(st.just("--t-end"), st.one_of(st.floats(max_value=-1e-300).map(repr),
                                            st.sampled_from(["nan", "inf", "NaN", "Infinity", "-inf", "abc", ""])))))
def test_bad_flags_exit_2_naming_the_option(flag):
    assert_refused(*run_cli(to_toml(good_scene()).encode(), *flag), named=flag[0])
