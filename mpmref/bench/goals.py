"""The performance goals, read off a finished ``mpmref bench`` run: one line per goal with its figure, its
bound and whether the run meets it (``None`` where the section that measures it was not run).

The goals (docs/performance.md, "Goals"): float32 Numba at two threads against Taichi's CPU backend on the
mpm88 and fluid3d scenes (``peer``, with ``--vs taichi``) and against hand-written single-file programs on the
throughput cases (``--yardstick FILE``: their JSON lines, run beside this command; they are not part of mpmref);
classic MPM over MLS-MPM in P2G and G2P on the Table-2 block, 2D and 3D, and the 3D P2G ratio against the
operation counts' prediction; two threads over one on the 32 768-particle mpm88 case, and with one core busy;
peak memory over the particle state (the Table-2 memory probe, at the Table-2 size); a 16³-cell body in a 256³
domain against a 32³ one, time and memory; a CPIC step over a plain one; a first run of mpm88 and a first
``verify --quick`` from empty caches against an older commit (``startup``); asynchronous stepping's efficiency, wall
ratios and one-level control (``async``).
"""

import statistics
from dataclasses import asdict, dataclass

#: two threads, float32, the Numba backend: the setting the goals are stated for
THREADS, DTYPE, BACKEND = 2, "float32", "numba"
#: the domain goal: the largest domain (cells per side) against the smallest, and the memory bound (bytes)
DOMAIN_BIG, DOMAIN_SMALL, DOMAIN_MEMORY = 256, 32, 200e6


@dataclass(frozen=True)
class Goal:
    """One goal's outcome. ``figure`` is ``None`` when the run did not measure it; ``at_most`` tells the
    direction of the bound."""

    name: str
    figure: float
    bound: float
    at_most: bool = False
    where: str = ""

    @property
    def met(self):
        if self.figure is None:
            return None
        return self.figure <= self.bound if self.at_most else self.figure >= self.bound


def _first(records, **match):
    return next((r for r in records if all(r.get(k) == v for k, v in match.items())), None)


def _peer_ratio(results, case):
    peer = results.get("peer") or {}
    r = _first(peer.get("results", []), case=case, threads=THREADS, backend=BACKEND)
    return None if r is None else r["ratio"]


def _table2_ratio(results, section, stage):
    ratios = (results.get(section) or {}).get("ratios", [])
    r = _first(ratios, backend=BACKEND, threads=THREADS, dtype=DTYPE) or _first(ratios, backend=BACKEND, dtype=DTYPE)
    return (None, "") if r is None else (r[stage], f"{r['threads']} thread(s)")


def _table2_prediction(results):
    """The 3D Table 2's measured P2G ratio (the stress included) over the operation count's prediction, less one."""
    ratios = (results.get("table2") or {}).get("ratios", [])
    r = _first(ratios, backend=BACKEND, threads=THREADS, dtype=DTYPE) or _first(ratios, backend=BACKEND, dtype=DTYPE)
    if r is None or r.get("predicted_p2g") is None:
        return None, ""
    return abs(r["p2g"] / r["predicted_p2g"] - 1.0), f"measured {r['p2g']:.2f}x, predicted {r['predicted_p2g']:.2f}x"


def _throughput(results, case, threads):
    r = _first((results.get("throughput") or {}).get("results", []), case=case, backend=BACKEND, threads=threads,
               dtype=DTYPE)
    return None if r is None else r


def _speedup(results):
    """Two threads over one on the mpm88 throughput case (32 768 particles): the particle-step rates' ratio."""
    one, two = _throughput(results, "mpm88", 1), _throughput(results, "mpm88", THREADS)
    if one is None or two is None:
        return None, ""
    return two["particle_steps_per_s"] / one["particle_steps_per_s"], "mpm88, 32,768 particles"


def _yardstick_ratio(results, case, dim):
    """mpmref's rate on a throughput case over a hand-written program's on the same dimension, particle count,
    thread count and dtype (the ``yardstick`` records of ``--yardstick``)."""
    ours = _throughput(results, case, THREADS)
    if ours is None:
        return None, ""
    theirs = next((y for y in results.get("yardstick") or () if y.get("dim") == dim and y.get("threads") == THREADS
                   and y.get("dtype") == "f32" and y.get("n_particles") == ours_particles(results, case)), None)
    if theirs is None:
        return None, ""
    return ours["particle_steps_per_s"] / theirs["particle_steps_per_s"], f"against {theirs.get('code', 'it')}"


def ours_particles(results, case):
    return next((c["particles"] for c in (results.get("throughput") or {}).get("cases", []) if c["case"] == case), None)


def _memory(results):
    r = _first((results.get("table2") or {}).get("memory") or [], backend=BACKEND, dtype=DTYPE)
    return (None, "") if r is None else (r["peak_over_state"], f"{r['particles']:,} particles")


def _domain(results):
    records = (results.get("domain") or {}).get("results", [])
    big = _first(records, backend=BACKEND, dtype=DTYPE, threads=THREADS, cells=DOMAIN_BIG)
    small = _first(records, backend=BACKEND, dtype=DTYPE, threads=THREADS, cells=DOMAIN_SMALL)
    if big is None or small is None:
        return None, None
    return big["step_s"] / small["step_s"], big.get("peak_bytes")


def _busy(results):
    r = _first((results.get("busy") or {}).get("results", []), load="one core busy")
    return (None, "") if r is None else (r["ratio"], f"{results['busy']['threading_layer']} threading layer")


def _cpic(results):
    r = _first((results.get("cpic") or {}).get("results", []), backend=BACKEND)
    return (None, "") if r is None else (r["ratio"], f"{r['threads']} thread(s), float64")


#: asynchronous stepping, per bench case: the efficiency (wall ratio over update ratio, ghosts included) the large
#: storks must reach, and the wall ratio (sync at the finest async step over async) of the example stork
ASYNC_EFFICIENCY_GOALS = (("stork2d-256", 0.75), ("stork3d-128", 0.75))
ASYNC_WALL_GOALS = (("stork2d", 1.5), ("stork2d-256", 2.5), ("stork3d-128", 2.3))
#: the one-level control (async on one level over sync at that step) within this fraction of 1, on every stork
ONE_LEVEL_OVERHEAD = 0.10
ONE_LEVEL_CASES = ("stork2d", "stork2d-128", "stork2d-256", "stork3d", "stork3d-128")


#: a user's first commands from empty caches (the ``startup`` section's labels): this checkout's wall time over the
#: older commit's (:data:`~mpmref.bench.startup.DEFAULT_AGAINST` unless ``--against`` says otherwise) at most
STARTUP_GOALS = (("run mpm88 (10 steps, numba)", 0.5), ("verify --quick", 0.6))


def _startup(results, command):
    """The startup section's wall ratio of ``command`` and where it stands: the median wall times and the commits."""
    section = results.get("startup") or {}
    r = _first(section.get("rows", []), command=command)
    if r is None:
        return None, ""
    this, against = (statistics.median(run["wall_s"] for run in r[side]) for side in ("this", "against"))
    return r["ratio"], (f"{section['this']}: {this:.1f} s, {section['against']}: {against:.1f} s, median of "
                        f"{len(r['this'])}")


def _async_ratio(results, case):
    """An async case's result (``None`` when the run did not measure it), with where it stands: the ideal, work and
    wall ratios and the comparison with synchronous stepping at its own CFL step."""
    r = _first((results.get("async") or {}).get("results", []), case=case, backend=BACKEND)
    if r is None:
        return None, ""
    where = (f"{r['threads']} thread(s), {r['particles']:,} particles; ideal {r['own_updates_ratio']:.2f}x, "
             f"work {r['updates_ratio']:.2f}x, wall {r['wall_ratio']:.2f}x; sync at its CFL step / async "
             f"{r['cfl_wall_ratio']:.2f}x")
    return r, where


def goals(results):
    """Every goal of a bench result dict (:func:`mpmref.bench.run_bench`), as :class:`Goal` records."""
    out = [Goal(f"{case} {THREADS} threads {DTYPE}: mpmref / Taichi CPU", _peer_ratio(results, case), bound)
           for case, bound in (("mpm88", 2.5), ("fluid3d", 2.5))]
    for case, dim, bound in (("mpm88", 2, 0.8), ("fluid3d", 3, 1.1)):
        figure, where = _yardstick_ratio(results, case, dim)
        out.append(Goal(f"{case} {THREADS} threads {DTYPE}: mpmref / hand-written", figure, bound, where=where))
    for section, dim in (("table2_2d", 2), ("table2", 3)):
        for stage in ("p2g", "g2p"):
            figure, where = _table2_ratio(results, section, stage)
            out.append(Goal(f"Table 2 {dim}D {stage.upper()}: classic MPM / MLS-MPM", figure, 1.8, where=where))
    figure, where = _table2_prediction(results)
    out.append(Goal("Table 2 3D P2G with the stress: |measured / predicted - 1|", figure, 0.25, True, where))
    for name, (figure, where), bound, at_most in (("2 threads over 1, idle", _speedup(results), 1.6, False),
                                                  ("peak memory / particle state", _memory(results), 1.5, True)):
        out.append(Goal(name, figure, bound, at_most, where))
    ratio, peak = _domain(results)
    out.append(Goal(f"{DOMAIN_BIG}^3 domain / {DOMAIN_SMALL}^3 domain, same body: step time", ratio, 1.5,
                    at_most=True))
    out.append(Goal(f"{DOMAIN_BIG}^3 domain: peak memory (MB)", None if peak is None else peak / 1e6,
                    DOMAIN_MEMORY / 1e6, at_most=True))
    figure, where = _busy(results)
    out.append(Goal("mpm88 example, one core busy: 2 threads / 1 thread, time", figure, 1.3, True, where))
    figure, where = _cpic(results)
    out.append(Goal("CPIC step / step without bodies", figure, 1.5, True, where))
    for command, bound in STARTUP_GOALS:
        figure, where = _startup(results, command)
        out.append(Goal(f"{command}, cold: wall / older commit's", figure, bound, True, where))
    for case, bound in ASYNC_EFFICIENCY_GOALS:
        r, where = _async_ratio(results, case)
        figure = None if r is None else r["implementation_efficiency"]
        out.append(Goal(f"{case}: async efficiency, wall ratio / update ratio", figure, bound, where=where))
    for case, bound in ASYNC_WALL_GOALS:
        r, where = _async_ratio(results, case)
        figure = None if r is None else r["wall_ratio"]
        out.append(Goal(f"{case}: sync at the finest async step / async, wall time", figure, bound, where=where))
    for case in ONE_LEVEL_CASES:
        r, where = _async_ratio(results, case)
        figure = None if r is None else abs(r["one_level_overhead"] - 1.0)
        out.append(Goal(f"{case}: one-level control / sync, time, |ratio - 1|", figure, ONE_LEVEL_OVERHEAD, True,
                        where))
    return out


def goals_section(results):
    """The ``goals`` section of the JSON document: one dict per goal with ``met``."""
    return [{**asdict(g), "met": g.met} for g in goals(results)]


def render_goals(section):
    """The goals as a table: figure, bound, met (``-``: not measured by this run)."""
    lines = [f"Goals ({BACKEND}, {DTYPE}, {THREADS} threads unless said; '-': not measured by this run)",
             f"{'goal':58}{'figure':>10}{'bound':>10}  met"]
    for g in section:
        figure = "-" if g["figure"] is None else f"{g['figure']:.3g}"
        sign = "<=" if g["at_most"] else ">="
        met = "-" if g["met"] is None else ("yes" if g["met"] else "no")
        where = f"  ({g['where']})" if g["where"] else ""
        lines.append(f"{g['name']:58}{figure:>10}{sign:>4}{g['bound']:>6.3g}  {met}{where}")
    return "\n".join(lines)
