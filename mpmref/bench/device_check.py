"""The GPU backend's device check: every check that needs a real GPU, in one command, as JSON lines.

Run on a machine with an NVIDIA GPU (docs/gpu.md, "Running the device check")::

    python -m mpmref.bench.device_check [--out DIR] [--workers N] [--yardstick PATH] [--sizes DIM:PARTICLES:CELLS,...]

It prints one JSON line per result on standard output (and writes them to ``DIR/device_check.jsonl``; the verify
report goes to a temporary folder unless ``--verify-out`` names one):

1. ``environment``: the GPU, the versions;
2. ``conformance``: the whole conformance harness on ``cuda`` (every stage of every backend, 2D and 3D, float64 at
   1e-12 and float32 at its tolerance), in ``--workers`` processes (the kernels' compilation dominates); one line
   per stage and dtype with its worst case, and one per failed case;
3. ``verify``: ``mpmref verify --quick --backend cuda`` (its cases' outcomes), in parallel with the harness;
4. ``trajectory``: 50 to 200 steps of four examples (a fluid, an elastic jelly, sand, a 3D fluid) on ``cuda`` and on
   the Numba backend, the largest difference of positions in cells and of velocities relative to the largest speed;
5. ``determinism``: two runs of 500 steps from the same state (2D, 262 144 particles, float32 and float64): the
   SHA-1 of the final positions and velocities of each; the opt-in atomic P2G alongside;
6. ``bench``: the ``cuda`` section of ``mpmref bench`` (:mod:`mpmref.bench.gpu`) at ``--sizes`` (default the
   million-particle cases, 2D and 3D, float32 and float64), with its goals.

A last line ``{"check": "done", ...}`` gives the wall time of each part. The exit status is 0 when every
correctness check passed (conformance, verify, determinism), 1 otherwise, 2 without a GPU.
"""

import argparse
import hashlib
import json
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from mpmref.bench.gpu import YARDSTICK, gpu_missing

#: the bench sizes of the device check by default: the goals' million-particle cases
DEFAULT_SIZES = {2: ((1_048_576, 512),), 3: ((1_048_576, 160),)}
#: the determinism runs: particles, cells, steps (gpu-facts: the yardstick's gather variant was checked so)
DETERMINISM = (262_144, 256, 500)


class Lines:
    """JSON lines to standard output and, with a folder, to ``device_check.jsonl`` there."""

    def __init__(self, out):
        self.path = None if out is None else Path(out) / "device_check.jsonl"
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.path.write_text("")

    def __call__(self, check, **fields):
        line = json.dumps({"check": check, **fields}, default=_plain)
        print(line, flush=True)
        if self.path is not None:
            with self.path.open("a") as fh:
                fh.write(line + "\n")


def _plain(value):
    return value.item() if isinstance(value, np.generic) else str(value)


# ------------------------------------------------------------------------------------------ conformance
def _check_chunk(names_and_dtype):
    """Run the conformance cases named (in a worker process); their outcomes as plain dicts."""
    from mpmref.conformance import check, make_cases

    names, dtype = names_and_dtype
    cases = [c for c in make_cases(dtype=dtype) if c.name in set(names)]
    report = check("cuda", cases, progress=False)
    return [{"case": r.case.name, "stage": r.case.stage, "dtype": dtype, "error": r.error, "rtol": r.rtol,
             "passed": r.passed, "output": r.worst_output, "note": r.note} for r in report.results]


def conformance_chunks(workers):
    """The harness's cases split into chunks for ``workers`` processes, cases of one kernel configuration together
    (a process compiles a configuration's kernels once)."""
    from mpmref.backends.cuda.kernels import Config
    from mpmref.conformance import make_cases

    chunks = []
    for dtype in ("float64", "float32"):
        groups = {}
        for case in make_cases(dtype=dtype):
            groups.setdefault(Config.of(case.scene()), []).append(case.name)
        per = max(1, -(-len(groups) // max(1, workers // 2)))
        keys = list(groups)
        for i in range(0, len(keys), per):
            chunks.append(([name for key in keys[i:i + per] for name in groups[key]], dtype))
    return chunks


def report_conformance(out, results):
    """One line per stage and dtype (cases, failed, worst error and case), one per failed case; whether all passed."""
    for dtype in ("float64", "float32"):
        for stage in dict.fromkeys(r["stage"] for r in results if r["dtype"] == dtype):
            rows = [r for r in results if r["dtype"] == dtype and r["stage"] == stage]
            worst = max(rows, key=lambda r: r["error"] / r["rtol"])
            out("conformance", dtype=dtype, stage=stage, cases=len(rows), failed=sum(not r["passed"] for r in rows),
                max_error=worst["error"], rtol=worst["rtol"], worst=worst["case"], output=worst["output"])
    for r in results:
        if not r["passed"]:
            out("conformance_failure", **r)
    return bool(results) and all(r["passed"] for r in results)


# ------------------------------------------------------------------------------------------- verify
def run_verify(out_dir, workers):
    """``mpmref verify --quick --backend cuda`` in this process (its subcommand, found whether or not mpmref is
    installed); returns its exit status and ``results.json``."""
    from verification.framework.cli import add_parser

    parser = argparse.ArgumentParser(prog="mpmref")
    add_parser(parser.add_subparsers())
    args = parser.parse_args(["verify", "--quick", "--backend", "cuda", "--out", str(out_dir), "--workers",
                              str(workers), "--no-progress"])
    status = args.func(args)
    results = Path(out_dir) / "results.json"
    return status, json.loads(results.read_text()) if results.exists() else None


def _verify_job(out_dir, workers):
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()):
        return run_verify(out_dir, workers)


# ------------------------------------------------------------------------------------------ trajectories
def trajectory_scenes():
    """Small scenes of the examples, for ``cuda`` against the Numba backend: ``(name, scene, steps)``."""
    from mpmref import Scene

    here = Path(__file__).resolve().parents[2] / "examples"
    out = []
    for name, steps in (("mpm88", 200), ("jelly", 200), ("sand", 100), ("fluid3d", 50)):
        path = here / f"{name}.toml"
        if path.exists():
            out.append((name, Scene.from_toml(path), steps))
    return out


def compare_trajectories(out):
    """Each scene's final state on ``cuda`` and on ``numba`` from the same particles: the largest position
    difference in cells and velocity difference relative to the largest speed."""
    from mpmref import Simulation

    for name, scene, steps in trajectory_scenes():
        runs = {}
        for backend in ("numba", "cuda"):
            sim = Simulation(scene, backend=backend)
            start = time.perf_counter()
            sim.run(steps=steps)
            runs[backend] = (sim.x.astype(np.float64), sim.v.astype(np.float64), time.perf_counter() - start)
        (xa, va, ta), (xb, vb, tb) = runs["numba"], runs["cuda"]
        out("trajectory", scene=name, dtype=scene.dtype.name, particles=len(xa), steps=steps,
            position_difference_cells=float(np.abs(xa - xb).max() / scene.grid.dx),
            velocity_difference_relative=float(np.abs(va - vb).max() / max(np.abs(va).max(), 1e-300)),
            numba_s=ta, cuda_s=tb)


# ------------------------------------------------------------------------------------------ determinism
def final_digest(backend_reference, scene, particles, steps):
    """SHA-1 of the final positions and velocities after ``steps`` resident steps of ``scene``."""
    from mpmref.backends import make_backend
    from mpmref.bench.throughput import run_steps

    backend = make_backend(backend_reference, scene)
    host = backend.to_host(run_steps(backend, backend.to_device(particles), scene.time.dt, steps))
    return hashlib.sha1(np.ascontiguousarray(host.x).tobytes() + np.ascontiguousarray(host.v).tobytes()).hexdigest()


def check_determinism(out):
    """Two runs of :data:`DETERMINISM` in float32 and float64, default and atomic P2G; whether the default's bits
    were the same."""
    from mpmref.bench.gpu import yardstick_scene
    from mpmref.scene.sampling import sample_particles

    particles, cells, steps = DETERMINISM
    same = True
    for dtype in ("float32", "float64"):
        scene = yardstick_scene(2, particles, cells, dtype)
        state = sample_particles(scene)
        for reference, mode in (("cuda", "gather"), ("mpmref.backends.cuda:atomic", "atomic")):
            digests = [final_digest(reference, scene, state, steps) for _ in range(2)]
            out("determinism", dtype=dtype, p2g=mode, particles=state.n, steps=steps, sha1=digests,
                identical=digests[0] == digests[1])
            same = same and (mode != "gather" or digests[0] == digests[1])
    return same


# ------------------------------------------------------------------------------------------------ main
def parse_sizes(text):
    """``DIM:PARTICLES:CELLS,...`` as the bench's sizes mapping."""
    sizes = {}
    for part in text.split(","):
        dim, particles, cells = (int(v) for v in part.split(":"))
        if dim not in (2, 3) or particles < 1 or cells < 8:
            raise argparse.ArgumentTypeError(f"{part}: expected DIM:PARTICLES:CELLS, DIM 2 or 3")
        sizes[dim] = sizes.get(dim, ()) + ((particles, cells),)
    return sizes


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m mpmref.bench.device_check", description=__doc__.split("\n")[0])
    parser.add_argument("--out", help="folder for device_check.jsonl (default: $OUT, else reports/device_check)")
    parser.add_argument("--verify-out", help="folder for the verify report (default: a temporary folder, so that the "
                        "output folder holds only device_check.jsonl)")
    parser.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2) - 2),
                        help="processes for the conformance harness (default: the cores less two)")
    parser.add_argument("--yardstick", help="the GPU yardstick program, run beside the bench (see mpmref.bench.gpu)")
    parser.add_argument("--sizes", type=parse_sizes, default=DEFAULT_SIZES,
                        help="bench cases as DIM:PARTICLES:CELLS,... (default: 2:1048576:512,3:1048576:160)")
    parser.add_argument("--skip", nargs="*", default=(), choices=("conformance", "verify", "trajectory",
                                                                  "determinism", "bench"), help="parts to leave out")
    args = parser.parse_args(argv)
    out_dir = Path(args.out or os.environ.get("OUT") or "reports/device_check")
    out = Lines(out_dir)
    if args.yardstick:
        os.environ[YARDSTICK] = str(Path(args.yardstick).resolve())
    missing = gpu_missing()
    if missing:
        out("environment", available=False, message=missing)
        return 2
    environment(out)
    walls, passed = {}, True
    start = time.perf_counter()
    context = get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.workers + 1, mp_context=context) as pool:
        verify_out = Path(args.verify_out or tempfile.mkdtemp(prefix="mpmref_verify_"))
        verify = None if "verify" in args.skip else pool.submit(_verify_job, verify_out, 4)
        if "conformance" not in args.skip:
            chunks = conformance_chunks(args.workers)
            results = [r for part in pool.map(_check_chunk, chunks) for r in part]
            passed = report_conformance(out, results) and passed
            walls["conformance"] = time.perf_counter() - start
        if verify is not None:
            status, summary = verify.result()
            cases = [{k: c.get(k) for k in ("case", "verdict", "passed", "wall_s", "error")}
                     for c in (summary or {}).get("cases", [])]
            out("verify", status=status, cases=cases)
            passed = passed and status == 0
            walls["verify"] = time.perf_counter() - start
    for name, part in (("trajectory", compare_trajectories), ("determinism", check_determinism)):
        if name not in args.skip:
            t = time.perf_counter()
            ok = part(out)
            passed = passed and ok is not False
            walls[name] = time.perf_counter() - t
    if "bench" not in args.skip:
        t = time.perf_counter()
        bench(out, args.sizes)
        walls["bench"] = time.perf_counter() - t
    out("done", passed=passed, wall_s=walls, total_s=time.perf_counter() - start)
    return 0 if passed else 1


def environment(out):
    """The GPU and the versions the figures depend on."""
    from importlib import metadata

    from mpmref.backends.cuda.runtime import device_name

    versions = {}
    for package in ("numpy", "numba", "numba-cuda", "cupy-cuda13x"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    out("environment", available=True, device=device_name(), cpus=os.cpu_count(), python=sys.version.split()[0],
        **versions)


def bench(out, sizes):
    """The ``cuda`` bench section at ``sizes``: one line per result, one per goal."""
    from mpmref.bench import BenchOptions
    from mpmref.bench.gpu import run_cuda

    section = run_cuda(BenchOptions(repeats=3), log=lambda message: print(message, file=sys.stderr), sizes=sizes)
    for r in section["results"]:
        out("bench", **{k: v for k, v in r.items() if k != "record"})
    for g in section["goals"]:
        out("goal", **g)


if __name__ == "__main__":
    sys.exit(main())
