"""Readable tables of the Table-2, throughput and peer sections (the JSON holds every figure; these show the
medians). The other sections render their own (:data:`mpmref.bench.sections.SECTIONS` says which renders which).
"""

METHOD_COLUMNS = (("mpm", "MPM"), ("mls", "MLS-MPM"))
STAGE_ROWS = (("p2g", "P2G"), ("g2p", "G2P"))


def seconds(t):
    """``t`` seconds as a short string in s, ms or us."""
    if t is None:
        return "-"
    if t >= 1.0:
        return f"{t:.3g} s"
    if t >= 1e-3:
        return f"{t * 1e3:.3g} ms"
    return f"{t * 1e6:.3g} us"


def megabytes(n):
    return "-" if n is None else f"{n / 2**20:.1f}"


def threads_label(k):
    return f"{k} thread" + ("s" if k > 1 else "")


def render_table2(section):
    """The talk's Table 2 once per backend, thread count and dtype: rows P2G and G2P, columns MPM,
    MLS-MPM and their ratio; then the peak-memory probe."""
    setup = section["setup"]
    lines = [f"Table 2 ({setup['dim']}D): P2G and G2P, {setup['cells_per_side']}^{setup['dim']} cells, "
             f"{setup['particles']:,} particles ({setup['particles_per_cell']} per cell at cell centre +-dx/4), "
             f"quadratic B-spline, {setup['material']}; median of repeats"]
    by = {(t["backend"], t["threads"], t["dtype"], t["method"], t["stage"]): t for t in section["timings"]}
    for ratio in section["ratios"]:
        key = (ratio["backend"], ratio["threads"], ratio["dtype"])
        lines += ["", f"{key[0]}, {threads_label(key[1])}, {key[2]}", *_table2_block(by, key, ratio)]
    if section.get("memory"):
        lines += ["", render_memory(section["memory"])]
    return "\n".join(lines)


def _table2_block(by, key, ratio):
    """Header, the P2G and G2P rows, and a line with the preparation and first-call times."""
    def figure(method, stage, field):
        return seconds(by[(*key, method, stage)][field])

    rows = [f"{'':6}{'MPM':>12}{'MLS-MPM':>12}{'MPM/MLS':>10}{'predicted':>11}"]
    for stage, label in STAGE_ROWS:
        cells = "".join(f"{figure(m, stage, 'median_s'):>12}" for m, _ in METHOD_COLUMNS)
        predicted = ratio.get(f"predicted_{stage}")
        guess = "" if predicted is None else f"{predicted:>10.2f}x"
        rows.append(f"{label:6}{cells}{ratio[stage]:>9.2f}x{guess}")
    firsts = ", ".join(f"{label} " + " / ".join(figure(m, stage, "first_call_s") for m, _ in METHOD_COLUMNS)
                       for stage, label in STAGE_ROWS)
    transfer = "-" if ratio["p2g_minus_stress"] is None else f"{ratio['p2g_minus_stress']:.2f}x"
    rows.append(f"      P2G minus the stress (stress {figure('mls', 'stress', 'median_s')}): MPM/MLS {transfer}; "
                f"shared preparation {figure('mls', 'prepare', 'median_s')}")
    rows.append(f"      first call (incl. JIT), MPM / MLS-MPM: {firsts}")
    return rows


def render_memory(records):
    lines = ["Peak memory of MLS-MPM steps (fresh process): peak/particles = (peak - baseline) / particle state; "
             "peak/state = (particles + step peak growth) / (particles + grid state)",
             f"{'backend':9}{'dtype':9}{'threads':>8}{'particles MB':>14}{'grid MB':>9}{'step peak MB':>14}"
             f"{'peak/state':>12}{'peak/particles':>16}"]
    for r in records:
        ratio = "-" if r["peak_over_state"] is None else f"{r['peak_over_state']:.2f}"
        particles = "-" if r["peak_over_particles"] is None else f"{r['peak_over_particles']:.2f}"
        lines.append(f"{r['backend']:9}{r['dtype']:9}{r['threads']:>8}{megabytes(r['particle_bytes']):>14}"
                     f"{megabytes(r['grid_bytes']):>9}{megabytes(r['step_peak_growth_bytes']):>14}{ratio:>12}"
                     f"{particles:>16}")
    return "\n".join(lines)


def render_throughput(section):
    """One row per case, backend, thread count and dtype: M particle-steps/s and the ratio to NumPy."""
    lines = ["Throughput of whole steps (median of repeats), M particle-steps/s",
             f"{'case':9}{'particles':>10}  {'backend':8}{'threads':>8}  {'dtype':8}{'M/s':>9}{'vs numpy':>10}"
             f"{'first call':>12}"]
    sizes = {c["case"]: c["particles"] for c in section["cases"]}
    for r in section["results"]:
        ratio = "-" if r["vs_numpy"] is None else f"{r['vs_numpy']:.2f}x"
        lines.append(f"{r['case']:9}{sizes[r['case']]:>10}  {r['backend']:8}{r['threads']:>8}  {r['dtype']:8}"
                     f"{r['particle_steps_per_s'] / 1e6:>9.3f}{ratio:>10}{seconds(r['first_call_s']):>12}")
    return "\n".join(lines)


def render_peer(section):
    """Rates of mpmref and the peer, their ratio, and the centre-of-mass agreement with its bound."""
    if not section["available"]:
        return f"Peer: not run. {section['message']}"
    lines = [f"Peer: Taichi {section['version']} CPU running mpmref's equations (mpmref/peers/taichi_mpm88.py), "
             f"{section['dtype']}, {section['steps']} steps per repeat",
             f"{'case':9}{'particles':>10}{'threads':>8}  {'backend':8}{'mpmref M/s':>11}{'Taichi M/s':>11}"
             f"{'ratio':>8}{'|d mean x|':>12}{'bound':>10}  agree"]
    for r in section["results"]:
        agree = {True: "yes", False: "NO", None: "n/a (walls reached)"}[r["agree"]]
        ours, theirs = (r[code]["particle_steps_per_s"] / 1e6 for code in ("mpmref", "taichi"))
        lines.append(f"{r['case']:9}{r['particles']:>10}{r['threads']:>8}  {r['backend']:8}{ours:>11.3f}{theirs:>11.3f}"
                     f"{r['ratio']:>7.2f}x{r['mean_position_difference']:>12.2e}{r['bound']:>10.2e}  {agree}")
    return "\n".join(lines)

