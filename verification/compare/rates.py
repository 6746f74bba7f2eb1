"""The false-alarm and detection rates of ``mpmref compare``, measured over seeds of a chaotic scene.

``python -m verification.compare.rates [--seeds 20] [--members 20] [--out DIR]`` runs, for each seed, the scene
``examples/outside_mpm/dam_break.toml`` with its randomly sampled water drawn from that seed, and judges against
ensembles of that seed (float64 and float32, the Numba backend):

* correct codes, which must pass: the NumPy reference (``mpmref run --backend numpy``), the outside program
  (``examples/outside_mpm``) summing its stencil in the reverse order, and the outside program in float32 against
  the float32 ensemble;
* the outside program with each planted bug (float64), which must fail.

It writes ``DIR/rates.json`` and ``DIR/rates.md`` (the table docs/comparing_runs.md quotes), and keeps each verdict's
measures in ``DIR/seed_<s>/measures.pkl``: a seed already there is judged again from them, not run again (a stopped
measurement resumes), and ``--rejudge`` runs nothing.
"""

import argparse
import json
import pickle
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from mpmref import Scene, Simulation
from mpmref.exchange import FrameError, export_start, initial_particles, read_frames
from mpmref.io.atomic import write_text_atomic

from ..framework.executor import Executor
from .comparison import DEFAULT_MEMBERS, frame_labels, frame_stops, measured, run_ensemble, scene_in_precision
from .verdict import judge

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "examples" / "outside_mpm" / "dam_break.toml"
PROGRAM = ROOT / "examples" / "outside_mpm" / "outside_mpm.py"
#: the codes judged: name -> (how it runs, its precision, whether it is correct)
CODES = {
    "numpy reference": ("numpy", "float64", True),
    "outside, reverse order": (["--reverse"], "float64", True),
    "outside, float32": (["--dtype", "float32"], "float32", True),
    **{f"bug {bug}": (["--bug", bug], "float64", False)
       for bug in ("stiffness", "wall-gravity", "half-dt-advect", "friction-sign")},
}


def seeded_scene(seed):
    """The dam break with its randomly sampled bodies drawn from ``seed``."""
    scene = Scene.from_toml(SCENE)
    source = {**scene.source, "bodies": [{**b, "seed": seed} if b.get("sampling") == "random" else b
                                         for b in scene.source["bodies"]],
              "output": {**scene.source.get("output", {}), "checkpoint": False}}
    return Scene.from_dict(source, base_dir=scene.base_dir)


def run_code(item):
    """Run one code of :data:`CODES` from the start in ``item = (name, start, out, scene source)``."""
    name, start, out, source = item
    how = CODES[name][0]
    if how == "numpy":
        Simulation(Scene.from_dict(source), backend="numpy", out_dir=out).run()
        return name
    subprocess.run([sys.executable, str(PROGRAM), "run", start, out, *how], check=True, capture_output=True)
    return name


def verdict_record(verdicts, correct):
    """What one judgement found: passed, the first failure's frame and statistics."""
    failure = next((v for v in verdicts if not v.passed), None)
    return {"passed": failure is None, "correct": correct,
            "first": None if failure is None else {"label": failure.label, "frame": failure.index,
                                                   "phase": failure.phase, "statistics": [n for n, _ in failure.left]}}


def one_seed(seed, members, executor, folder):
    """Run every code and both ensembles of ``seed``; judge; keep the measures in ``folder``. Returns the records."""
    scene = seeded_scene(seed)
    with tempfile.TemporaryDirectory() as tmp:
        start = Path(tmp) / "start"
        export_start(scene, start)
        items = [(name, str(start), str(Path(tmp) / f"code{k}"), scene.source) for k, name in enumerate(CODES)]
        executor.map(run_code, items)
        frames, records, ids = {}, {}, initial_particles(scene).id
        for name, _, out, _ in items:
            try:
                frames[name] = read_frames(Path(out) / "particles.pvd", scene.dim, ids)
            except FrameError as exc:  # refused before any comparison: a blown-up run is caught there
                records[name] = refused_record(exc, CODES[name][2])
    measures = {}
    for dtype in ("float64", "float32"):
        precise = scene_in_precision(scene, dtype)
        names = [name for name in CODES if CODES[name][1] == dtype and name in frames]
        if not names:
            continue
        stops = frame_stops(precise, frames[names[0]])
        ensemble = run_ensemble(precise, stops, "numba", members, seed, executor)
        for name in names:
            m = measured(precise, frames[name], ensemble)
            m.particle_spread = m.particle_deviation = None  # what the verdict does not read
            labels = frame_labels(precise, frames[name])
            measures[name] = (labels, m)
            records[name] = verdict_record(rejudged(labels, m), CODES[name][2])
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "measures.pkl").write_bytes(pickle.dumps(measures))
    write_text_atomic(folder / "refused.json", json.dumps({k: r for k, r in records.items() if k not in measures}))
    return {name: records[name] for name in CODES}


def refused_record(error, correct):
    """A code whose frames ``compare`` refused (:class:`~mpmref.exchange.FrameError`): it failed there."""
    return {"passed": False, "correct": correct,
            "first": {"label": f"refused: {Path(error.path).name}", "frame": None, "phase": "refused",
                      "statistics": [error.reason]}}


def rejudged(labels, m):
    return judge(labels, m)


def rates_table(by_seed):
    """Per code: how often it passed (correct codes) or failed (bugs), its first failing frames and the statistics
    named there."""
    table = {}
    for name in CODES:
        records = [seeds[name] for seeds in by_seed.values()]
        failures = [r["first"] for r in records if not r["passed"]]
        table[name] = {"correct": CODES[name][2], "seeds": len(records), "passed": len(records) - len(failures),
                       "first_frames": dict(Counter(f["label"] for f in failures)),
                       "phases": dict(Counter(f["phase"] for f in failures)),
                       "statistics": dict(Counter(f["statistics"][0] for f in failures).most_common(5))}
    return table


def rates_markdown(table, members, wall):
    lines = ["| code | seeds | passed | failed | first failing frames | first statistic named |",
             "|---|---|---|---|---|---|"]
    for name, row in table.items():
        frames = ", ".join(f"{k} ({n})" for k, n in row["first_frames"].items()) or "-"
        stats = ", ".join(f"{k} ({n})" for k, n in row["statistics"].items()) or "-"
        lines.append(f"| {name} | {row['seeds']} | {row['passed']} | {row['seeds'] - row['passed']} | {frames} | "
                     f"{stats} |")
    lines.append(f"\nEnsembles of {members} members; {wall / 60:.1f} min in all.")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--members", type=int, default=DEFAULT_MEMBERS)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--out", type=Path, default=Path("reports") / "compare_rates")
    parser.add_argument("--rejudge", action="store_true", help="judge the kept measures again; run nothing")
    args = parser.parse_args(argv)
    executor, started, by_seed = Executor(workers=args.workers), time.perf_counter(), {}
    for seed in range(1, args.seeds + 1):
        folder = args.out / f"seed_{seed}"
        if args.rejudge or (folder / "measures.pkl").is_file():  # judged again, or a seed an earlier run finished
            kept = pickle.loads((folder / "measures.pkl").read_bytes())
            records = {**json.loads((folder / "refused.json").read_text()),
                       **{name: verdict_record(rejudged(*kept[name]), CODES[name][2]) for name in kept}}
            by_seed[seed] = {name: records[name] for name in CODES}
        else:
            by_seed[seed] = one_seed(seed, args.members, executor, folder)
        print(f"seed {seed}: " + "; ".join(f"{k} {'pass' if r['passed'] else 'FAIL ' + r['first']['label']}"
                                           for k, r in by_seed[seed].items()), flush=True)
    table = rates_table(by_seed)
    wall = time.perf_counter() - started
    write_text_atomic(args.out / "rates.json", json.dumps({"members": args.members, "wall_s": wall, "rates": table,
                                                           "seeds": by_seed}, indent=1))
    write_text_atomic(args.out / "rates.md", rates_markdown(table, args.members, wall))
    print(rates_markdown(table, args.members, wall))
    return 0


if __name__ == "__main__":
    sys.exit(main())
