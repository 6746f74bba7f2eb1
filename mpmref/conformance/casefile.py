"""One case in one file: a state that ``mpmref conformance search`` found, replayable as a regression case.

A case file is one uncompressed ``.npz`` without pickled objects, as an exported case is (:mod:`.vectors`): the inputs
``in_<name>``, the reference's outputs ``out_<name>``, and ``case``, a 0-d string holding the case as JSON: its stage,
dimension, dtype, tolerance, the scene as declared, what each particle holds (``notes``) and how it was found. ``mpmref
conformance check --backend B --case FILE`` reruns it; in a test, ``check(candidate, [load_case(FILE)])``
(docs/conformance.md, "Searching for disagreement").
"""

import json

import numpy as np

from .case import GivenCase
from .extremes import Extreme
from .vectors import jsonable, write_npz

CASE_FORMAT = "mpmref-case"
CASE_VERSION = 1


def save_case(case, path, found=None):
    """Write ``case`` (its inputs, the reference's outputs on them and the case's description) to ``path``; ``found``
    (JSON-ready) says how it was found. Written atomically; returns ``path``."""
    inputs = case.inputs()
    outputs = case.reference(inputs)
    record = {"format": CASE_FORMAT, "version": CASE_VERSION, "name": case.name, "stage": case.stage,
              "dim": case.dim, "variant": case.variant, "dtype": case.dtype, "rtol": case.rtol, "source": case.source,
              "holds": None if case.extreme is None else case.extreme.holds, "notes": case.notes(),
              "scene": case.scene_dict, "found": found}
    arrays = {"case": np.array(json.dumps(jsonable(record))),
              **{f"in_{k}": np.asarray(a) for k, a in inputs.items()},
              **{f"out_{k}": np.asarray(a) for k, a in outputs.items()}}
    write_npz(path, arrays)
    return path


def load_case(path):
    """The :class:`~.case.GivenCase` of the case file ``path`` (:func:`save_case`); a file that is not one raises
    :class:`ValueError` naming it."""
    with np.load(path, allow_pickle=False) as data:
        if "case" not in data.files:
            raise ValueError(f"{path}: not a conformance case file (no 'case' entry; see mpmref conformance search)")
        record = json.loads(str(data["case"]))
        given = {k[len("in_"):]: data[k] for k in data.files if k.startswith("in_")}
    if record.get("format") != CASE_FORMAT:
        raise ValueError(f"{path}: format {record.get('format')!r}, expected {CASE_FORMAT!r}")
    holds = record.get("holds")
    extreme = None if holds is None else Extreme("found", holds)
    notes = record.get("notes")
    return GivenCase(record["stage"], record["dim"], record["variant"], record["scene"], record["dtype"],
                     source=record.get("source"), extreme=extreme, given=given,
                     given_notes=None if notes is None else tuple(notes))
