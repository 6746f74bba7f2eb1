"""The checks every scene section is made of: each returns the validated value or raises a
:class:`~mpmref.errors.SceneError` naming the field (dotted path), the value given and what is allowed."""

import math

import numpy as np

from ..errors import SceneError


def fail(path, value, allowed):
    """Raise the :class:`~mpmref.errors.SceneError` of field ``path``."""
    raise SceneError(path, value, allowed)


def _full(path, key):
    return f"{path}.{key}" if path else key


def _given(data, key, path, required, expected):
    """Whether ``data`` has ``key``; a missing ``required`` key is refused as not ``expected``."""
    if key in data:
        return True
    if required:
        fail(_full(path, key), None, f"{expected} (required)")
    return False


def section(data, path, allowed_keys):
    """``data`` itself, checked to be a table whose keys are all in ``allowed_keys``."""
    if not isinstance(data, dict):
        fail(path, data, "a table (mapping)")
    unknown = sorted(set(data) - set(allowed_keys))
    if unknown:
        fail(_full(path, unknown[0]), data[unknown[0]], f"one of the known keys {sorted(allowed_keys)}")
    return data


def number(data, key, path, default=None, lo=None, hi=None, lo_open=False, hi_open=False, required=False):
    """The finite number ``data[key]`` (a float) within the bounds, or ``default`` when it is absent."""
    full = _full(path, key)
    if not _given(data, key, path, required, f"a number{range_text(lo, hi, lo_open, hi_open)}"):
        return default
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        fail(full, value, f"a finite number{range_text(lo, hi, lo_open, hi_open)}")
    bad_lo = lo is not None and (value <= lo if lo_open else value < lo)
    bad_hi = hi is not None and (value >= hi if hi_open else value > hi)
    if bad_lo or bad_hi:
        fail(full, value, f"a number{range_text(lo, hi, lo_open, hi_open)}")
    return float(value)


def range_text(lo, hi, lo_open, hi_open):
    """`` in [lo, hi]`` with the interval's brackets (empty when unbounded)."""
    if lo is None and hi is None:
        return ""
    left = "(" if lo_open else "["
    right = ")" if hi_open else "]"
    return f" in {left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}{right}"


def integer(data, key, path, default=None, lo=None, hi=None, required=False):
    """The integer ``data[key]`` in ``[lo, hi]``, or ``default`` when it is absent."""
    full = _full(path, key)
    if not _given(data, key, path, required, f"an integer in [{lo}, {hi}]"):
        return default
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int) or (lo is not None and value < lo) or (
        hi is not None and value > hi
    ):
        fail(full, value, f"an integer in [{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]")
    return int(value)


def choice(data, key, path, options, default=None, required=False):
    """``data[key]``, one of ``options``, or ``default`` when it is absent."""
    if not _given(data, key, path, required, f"one of {list(options)}"):
        return default
    if data[key] not in options:
        fail(_full(path, key), data[key], f"one of {list(options)}")
    return data[key]


def flag(data, key, path, default):
    """The boolean ``data[key]``, or ``default`` when it is absent."""
    value = data.get(key, default)
    if not isinstance(value, bool):
        fail(_full(path, key), value, "true or false")
    return value


def vector(data, key, path, dim, default=None, required=False, positive=False):
    """``data[key]`` as a float64 array of ``dim`` finite numbers (one number stands for all ``dim``), or
    ``default`` (as an array, or ``None``) when it is absent."""
    full = _full(path, key)
    if not _given(data, key, path, required, f"a list of {dim} numbers"):
        return None if default is None else np.array(default, dtype=np.float64)
    value = data[key]
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * dim
    ok = isinstance(value, (list, tuple)) and len(value) == dim and all(
        isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in value
    )
    if not ok or (positive and min(value) <= 0):
        fail(full, value, f"a list of {dim} finite{' positive' if positive else ''} numbers")
    return np.array(value, dtype=np.float64)


def matrix(data, key, path, dim, default=None):
    """``data[key]`` as a (``dim``, ``dim``) float64 array: a list of ``dim`` rows of ``dim`` finite numbers each, or
    ``default`` (as an array) when it is absent."""
    if key not in data:
        return None if default is None else np.array(default, dtype=np.float64)
    value = data[key]
    ok = isinstance(value, (list, tuple)) and len(value) == dim and all(
        isinstance(row, (list, tuple)) and len(row) == dim
        and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in row)
        for row in value)
    if not ok:
        fail(_full(path, key), value, f"a {dim} x {dim} matrix: a list of {dim} rows of {dim} finite numbers each")
    return np.array(value, dtype=np.float64)
