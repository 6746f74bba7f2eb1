"""What a study varies: dotted scene keys, their values, and the scenes they make, each validated before any run.

A key is a dotted path into the scene's TOML declarations: ``grid.cells``, ``time.dt``, ``time.cfl``,
``method.scheme``, ``bodies[0].ppc``, ``materials.rubber.E``. Its values are written as in a scene file (``16``,
``0.5``, ``1e-3``, ``true``, ``"apic"``, ``[1.0, 0.0]``; quotes around a string are optional), so each value has
the type the validator expects, and a wrong one is refused by the validator naming the field. Setting a key
that a scene gives one of (``grid.dx`` or ``grid.cells``, ``time.dt`` or ``time.cfl``, ``time.steps`` or
``time.t_end``) removes the other. Several ``--vary`` give the product of their values; keys linked by ``:``
vary together, level by level (``grid.cells:time.dt=32:0.01,64:0.005`` refines space and time at once).
"""

import copy
import itertools
import re
import tomllib
from dataclasses import dataclass

from mpmref import Scene
from mpmref.errors import ArgumentError, SceneError
from mpmref.scene.sampling import sample_particles

#: keys of which a scene declares one (setting one removes the other)
ALTERNATIVES = {("grid", "dx"): "cells", ("grid", "cells"): "dx", ("time", "dt"): "cfl", ("time", "cfl"): "dt",
                ("time", "steps"): "t_end", ("time", "t_end"): "steps"}
#: what ``--vary`` accepts, for messages
SYNTAX = ("KEY=V1,V2,... with KEY a dotted scene key such as grid.cells, time.dt, method.scheme, bodies[0].ppc or "
          "materials.NAME.E, values written as in the scene file (KEY1:KEY2=V1:W1,V2:W2 varies keys together)")
_PART = re.compile(r"([A-Za-z0-9_-]+)((?:\[\d+\])*)$")


@dataclass(frozen=True)
class Variation:
    """One ``--vary``: its ``keys`` (several when linked) and ``levels``, one tuple of values (a value per key)
    per level."""

    keys: tuple
    levels: tuple

    @classmethod
    def of(cls, key, values):
        """From Python: ``key`` a dotted key (or a tuple of linked keys) and its values (tuples when linked)."""
        keys = (key,) if isinstance(key, str) else tuple(key)
        levels = tuple(tuple(v) if len(keys) > 1 else (v,) for v in values)
        return checked(cls(keys, levels), f"{':'.join(keys)}={values!r}")


def parse_vary(text):
    """The :class:`Variation` of a ``--vary`` option (``KEY=V1,V2,...``); :class:`~mpmref.errors.ArgumentError`
    naming what is wrong."""
    keys_text, equals, values_text = text.partition("=")
    keys = tuple(k.strip() for k in keys_text.split(":"))
    if not equals or not all(keys) or not values_text.strip():
        raise ArgumentError("--vary", text, SYNTAX)
    levels = []
    for level in split_top_level(values_text, ","):
        values = split_top_level(level, ":")
        if len(values) != len(keys):
            raise ArgumentError("--vary", text, f"{len(keys)} value(s) per level joined by ':', one for each of "
                                f"{', '.join(keys)} (the level {level!r} has {len(values)})")
        levels.append(tuple(parse_value(v) for v in values))
    return checked(Variation(keys, tuple(levels)), text)


def checked(variation, text):
    """``variation``, once its keys parse and its levels are distinct."""
    for key in variation.keys:
        key_path(key, text)
    if not variation.levels:
        raise ArgumentError("--vary", text, "at least one value")
    if len(set(map(repr, variation.levels))) != len(variation.levels):
        raise ArgumentError("--vary", text, "distinct values (a value given twice would run twice)")
    return variation


def split_top_level(text, separator):
    """``text`` split at ``separator`` outside brackets and quotes (so ``[1, 0],[2, 0]`` is two values)."""
    parts, depth, quote, start = [], 0, None, 0
    for i, c in enumerate(text):
        if quote:
            quote = None if c == quote else quote
        elif c in "\"'":
            quote = c
        elif c in "[{":
            depth += 1
        elif c in "]}":
            depth -= 1
        elif c == separator and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    return [p.strip() for p in parts + [text[start:]]]


def parse_value(text):
    """A value as a scene file writes it (a TOML value: ``16``, ``0.5``, ``true``, ``"apic"``, ``[1, 0]``), else a
    number Python reads (``.5``), else the text itself (an unquoted string such as ``apic``)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        pass
    for number in (int, float):
        try:
            return number(text)
        except ValueError:
            pass
    return text


def key_path(key, text=None):
    """The path of a dotted key, its table names and list indices: ``bodies[0].ppc`` -> ``("bodies", 0, "ppc")``."""
    path = []
    for part in key.split("."):
        m = _PART.match(part)
        if not m:
            raise ArgumentError("--vary", text or key, f"{SYNTAX}; {part!r} of {key!r} is not a key")
        path.append(m.group(1))
        path += [int(i) for i in re.findall(r"\[(\d+)\]", m.group(2))]
    return tuple(path)


def dotted(path):
    """The dotted key of a path (the inverse of :func:`key_path`), as :class:`~mpmref.errors.SceneError` names
    fields."""
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")


def assign(data, key, value):
    """Set ``key`` to ``value`` in the scene declarations ``data`` (in place). Missing tables on the way are created
    (``[method]`` in a scene that declares none); a list index must exist. Returns the keys of the tables created."""
    path, node, created = key_path(key), data, []
    for depth, part in enumerate(path[:-1]):
        here = path[:depth + 1]
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                count = len(node) if isinstance(node, list) else 0
                has = f"{count}, indices 0 to {count - 1}" if count else "none"
                raise SceneError(dotted(here), None, f"an entry the scene has (it has {has}); --vary {key} names "
                                 "one it does not have")
        elif not isinstance(node, dict):
            raise SceneError(dotted(here[:-1]), node, f"a table, so that --vary {key} can set a key in it")
        elif part not in node:
            node[part] = {}
            created.append(dotted(here))
        node = node[part]
    last = path[-1]
    if isinstance(last, int) and not (isinstance(node, list) and last < len(node)):
        raise SceneError(key, None, f"an existing list entry (--vary {key})")
    if not isinstance(last, int) and not isinstance(node, dict):
        raise SceneError(dotted(path[:-1]), node, f"a table, so that --vary {key} can set a key in it")
    alternative = ALTERNATIVES.get(path[-2:]) if len(path) == 2 else None
    if alternative is not None:
        node.pop(alternative, None)
    node[last] = value
    return created


def combinations(variations):
    """The runs of a study: one ``{key: value}`` per combination of levels (the product over the variations, the
    first varying slowest; linked keys together)."""
    keys = [k for v in variations for k in v.keys]
    repeated = sorted({k for k in keys if keys.count(k) > 1})
    if repeated:
        raise ArgumentError("--vary", repeated[0], "each key in one --vary only (link keys with ':' to vary them "
                            "together)")
    return [{k: value for v, level in zip(variations, levels) for k, value in zip(v.keys, level)}
            for levels in itertools.product(*(v.levels for v in variations))]


def run_scene(declarations, params, base_dir, extra=None):
    """The declarations of one run (``params`` applied to a copy of ``declarations``, then ``extra(data)``, which the
    study uses for its own output settings) and its validated :class:`~mpmref.scene.Scene`, sampled once so that a
    body outside the grid is found now. A :class:`~mpmref.errors.SceneError` names the run's parameters (and the
    tables the variation created, where a misspelt name made one)."""
    data = copy.deepcopy(declarations)
    created = [table for key, value in params.items() for table in assign(data, key, value)]
    if extra is not None:
        extra(data)
    try:
        scene = Scene.from_dict(data, base_dir=base_dir)
        sample_particles(scene)
    except SceneError as exc:
        made = f"; --vary made the table(s) {', '.join(created)}, which the scene did not have" if created else ""
        raise SceneError(exc.field, exc.value, f"{exc.allowed} (in the study's run {label(params)}{made})") from None
    return data, scene


def label(params):
    """``key=value, ...`` of a run's parameters (``the scene as it is`` when nothing is varied)."""
    return ", ".join(f"{k}={v}" for k, v in params.items()) or "the scene as it is"
