"""The files of ``mpmref compare``: ``results.json``, ``index.html``, the figures and the VTK file of where the code's
particles part from the control's.

* ``results.json``: the verdict, the first frame where the code leaves the ensemble (its statistics and materials,
  the particles that moved most), and every frame's figures;
* ``deviation.png``: the code's particle distance from the control and the ensemble's spread against time, with the
  round-off limit; ``test.png``: each frame's test figure against its threshold; ``statistics_<material>.png``: each
  statistic against time, the ensemble's band and the code's line;
* ``deviation_<step>.vtu``: the code's particles at the first frame where it leaves the ensemble (or its last frame),
  with each particle's distance from the control (``deviation``), the ensemble's largest distance of that particle
  (``ensemble_spread``) and their ratio: open it in ParaView beside the code's own frame to see where the departure
  starts.
"""

import html
import json
import math
from pathlib import Path

import numpy as np
from matplotlib.ticker import SymmetricalLogLocator

from mpmref.io.atomic import write_text_atomic
from mpmref.io.vtk import write_particles_vtu

from ..framework.html_report import figure_html, page
from ..framework.report import pyplot, save_figure
from .comparison import describe_method
from .verdict import ALPHA, PARTICLE_FACTOR

#: particles listed where the departure starts
TOP_PARTICLES = 10
#: statistics named in the one-line verdict (results.json and index.html list all)
SUMMARY_STATISTICS = 5
#: statistics panels per row of a material's figure
COLUMNS = 6


def times(comparison):
    """Each frame's time (its step times Δt when it gives only its step)."""
    dt = comparison.scene.time.dt
    return np.array([f.time if f.time is not None else f.step * dt for f in comparison.frames])


def judged_frame(comparison):
    """The frame the report shows particles of: the first failing one, else the last."""
    failure = comparison.first_failure
    return failure.index if failure is not None else len(comparison.frames) - 1


def departure(comparison, index):
    """The particles that moved most from the control at frame ``index``: ``[{id, x, deviation, ensemble_spread}]``."""
    m = comparison.measures
    deviation, spread = m.particle_deviation[index], m.particle_spread[index]
    order = np.argsort(-deviation, kind="stable")[:TOP_PARTICLES]
    x = comparison.frames[index].x
    return [{"id": int(i), "x": x[i].tolist(), "deviation": float(deviation[i]), "ensemble_spread": float(spread[i])}
            for i in order]


def summary(comparison):
    """The verdict in one line."""
    failure = comparison.first_failure
    if failure is None:
        return (f"PASSED: every one of {len(comparison.frames)} frames lies in the ensemble "
                f"({comparison.members} members)")
    stats = ", ".join(f"{name} (z = {z:.3g})" for name, z in failure.left[:SUMMARY_STATISTICS])
    if len(failure.left) > SUMMARY_STATISTICS:
        stats += f" and {len(failure.left) - SUMMARY_STATISTICS} more (results.json)"
    return (f"FAILED: the code leaves the ensemble at {failure.label} (frame {failure.index}, {failure.phase} "
            f"phase): {failure.reason()}; statistics: {stats}; materials: {', '.join(failure.materials())}")


def _finite(value):
    return None if value is None or not math.isfinite(value) else value


def frame_rows(comparison):
    """Every frame's figures, JSON-ready."""
    rows = []
    for v, t in zip(comparison.verdicts, times(comparison)):
        rows.append({"frame": v.index, "step": v.step, "time": float(t), "phase": v.phase, "passed": v.passed,
                     "spread": v.spread, "deviation": v.deviation, "particle_limit": v.particle_limit,
                     "t2": v.t2, "t2_limit": _finite(v.t2_limit), "components": v.components,
                     "z_limit": _finite(v.z_limit), "largest_z": max(v.z.items(), key=lambda i: abs(i[1]))[0],
                     "left": [{"statistic": n, "z": z} for n, z in v.left]})
    return rows


def results(comparison, files):
    """``results.json``'s content."""
    c = comparison
    failure = c.first_failure
    first = None if failure is None else {
        "frame": failure.index, "step": failure.step, "time": failure.time, "phase": failure.phase,
        "reason": failure.reason(), "statistics": [{"statistic": n, "z": z} for n, z in failure.left],
        "materials": failure.materials(), "particles": departure(c, failure.index)}
    return {"passed": c.passed, "summary": summary(c), "first_failure": first, "scene": c.scene.name,
            "dtype": c.dtype.name, "backend": c.backend, "members": c.members, "seed": c.seed, "alpha": ALPHA,
            "particle_factor": PARTICLE_FACTOR, "roundoff_limit": c.measures.roundoff_limit,
            "method": describe_method(c), "wall_s": c.wall_s, "ran_on": c.where, "statistics": c.measures.names,
            "frames_read": [str(f.path) for f in c.frames], "frames": frame_rows(c), "files": files}


def _positive(values):
    """``values`` with the zeros (a run equal to the control, to the bit) left out of a log plot."""
    values = np.asarray(values, dtype=np.float64)
    return np.where(values > 0.0, values, np.nan)


def deviation_figure(comparison, path):
    plt = pyplot()
    t = times(comparison)
    m = comparison.measures
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.semilogy(t, _positive(m.spreads), "o-", color="tab:gray", label="ensemble spread")
    ax.semilogy(t, _positive(m.deviations), "s-", color="tab:red", label="code's deviation")
    ax.axhline(m.roundoff_limit, ls="--", color="k", lw=1, label="round-off limit")
    _mark_failure(ax, comparison, t)
    ax.set_xlabel("time")
    ax.set_ylabel("largest particle distance from the control")
    ax.legend(fontsize=8)
    return save_figure(fig, path, "The code's largest particle distance from the control and the ensemble's, against "
                       "time (a frame where the code equals the control to the bit is left out): while the "
                       f"ensemble's is below the round-off limit, the code's must stay within {PARTICLE_FACTOR:g} "
                       "times it.")


def _mark_failure(ax, comparison, t):
    failure = comparison.first_failure
    if failure is not None:
        ax.axvline(t[failure.index], color="tab:red", lw=1, alpha=0.6)


def test_figure(comparison, path):
    plt = pyplot()
    t = times(comparison)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    z = [max(abs(x) for x in v.z.values()) for v in comparison.verdicts]
    ax.semilogy(t, np.maximum(z, 1e-3), "o-", label="largest |z|")
    ax.semilogy(t, [v.z_limit for v in comparison.verdicts], "--", label="|z| limit")
    ensemble = [i for i, v in enumerate(comparison.verdicts) if v.t2 is not None]
    if ensemble:
        ax.semilogy(t[ensemble], [max(comparison.verdicts[i].t2, 1e-3) for i in ensemble], "s-", label="T^2")
        ax.semilogy(t[ensemble], [comparison.verdicts[i].t2_limit for i in ensemble], ":", label="T^2 limit")
    _mark_failure(ax, comparison, t)
    ax.set_xlabel("time")
    ax.legend(fontsize=8)
    return save_figure(fig, path, "Each frame's tests: the largest standardised statistic |z| and, once the ensemble "
                       "has left round-off, Hotelling's T^2 on the leading principal components, against their limits.")


def statistics_figures(comparison, folder):
    """One figure per material: each statistic's departure from the ensemble's mean against time, the members' band
    (smallest to largest) and the code's line, on a scale linear within the statistic's round-off floor and
    logarithmic beyond (departures of round-off and of a bug both show)."""
    plt = pyplot()
    t = times(comparison)
    m = comparison.measures
    mean = m.samples.mean(axis=1)
    paths = []
    for material in dict.fromkeys(name.split(":")[0] for name in m.names):
        columns = [j for j, name in enumerate(m.names) if name.startswith(material + ":")]
        rows = math.ceil(len(columns) / COLUMNS)
        fig, axes = plt.subplots(rows, COLUMNS, figsize=(2.6 * COLUMNS, 2.0 * rows), squeeze=False)
        for ax, j in zip(axes.flat, columns):
            band = m.samples[:, :, j] - mean[:, j:j + 1]
            ax.fill_between(t, band.min(axis=1), band.max(axis=1), color="tab:gray", alpha=0.5, lw=0)
            ax.plot(t, m.code[:, j] - mean[:, j], color="tab:red", lw=1)
            ax.set_yscale("symlog", linthresh=m.floor[j])
            ax.yaxis.set_major_locator(SymmetricalLogLocator(linthresh=m.floor[j], base=1e3))
            _mark_failure(ax, comparison, t)
            ax.set_title(m.names[j].split(":")[1], fontsize=8)
            ax.tick_params(labelsize=6)
        for ax in list(axes.flat)[len(columns):]:
            ax.axis("off")
        fig.tight_layout()
        paths.append(save_figure(fig, Path(folder) / f"statistics_{material}.png",
                                 f"Material {material}: each statistic minus the ensemble's mean against time, the "
                                 "members' band (grey) and the code (red); linear within the statistic's round-off "
                                 "floor, logarithmic beyond."))
    return paths


def deviation_vtu(comparison, folder):
    """``deviation_<step>.vtu`` of the frame :func:`judged_frame` (module docstring)."""
    index = judged_frame(comparison)
    frame = comparison.frames[index]
    deviation, spread = comparison.measures.particle_deviation[index], comparison.measures.particle_spread[index]
    ratio = deviation / np.maximum(spread, np.finfo(np.float64).tiny)
    ids = np.arange(len(frame.x), dtype=np.int64)
    step = comparison.verdicts[index].step
    path = Path(folder) / f"deviation_{step if step is not None else index:06d}.vtu"
    write_particles_vtu(path, frame.x, {"id": ids, "deviation": deviation, "ensemble_spread": spread,
                                        "deviation_over_spread": ratio})
    return path


def index_html(comparison, figures, vtu):
    e = html.escape
    c = comparison
    style = "pass" if c.passed else "fail"
    rows = "".join(
        f"<tr class='{'' if v.passed else 'fail'}'><td>{v.index}</td><td>{e(v.label)}</td><td>{v.phase}</td>"
        f"<td class='num'>{v.spread:.3g}</td><td class='num'>{v.deviation:.3g}</td>"
        f"<td class='num'>{'' if v.t2 is None else f'{v.t2:.3g} / {v.t2_limit:.3g}'}</td>"
        f"<td class='num'>{max(abs(z) for z in v.z.values()):.3g} / {v.z_limit:.3g}</td>"
        f"<td class='{'pass' if v.passed else 'FAIL'}'>{'pass' if v.passed else 'FAIL'}</td>"
        f"<td>{e(', '.join(n for n, _ in v.left))}</td></tr>" for v in c.verdicts)
    particles = ""
    failure = c.first_failure
    if failure is not None:
        items = "".join(f"<tr><td>{p['id']}</td><td>{e(str(np.round(p['x'], 6).tolist()))}</td>"
                        f"<td class='num'>{p['deviation']:.3g}</td><td class='num'>{p['ensemble_spread']:.3g}</td></tr>"
                        for p in departure(c, failure.index))
        particles = (f"<h2>Where the departure starts</h2><p>The particles that moved most from the control at "
                     f"{e(failure.label)} (all of them in <a href='{e(vtu.name)}'>{e(vtu.name)}</a>, to open in "
                     "ParaView beside the code's own frame):</p><table><tr><th>id</th><th>x</th><th>distance</th>"
                     f"<th>ensemble's distance</th></tr>{items}</table>")
    body = (f"<h1>mpmref compare: {e(c.scene.name)}</h1><div class='verdict {style}'>{e(summary(c))}</div>"
            f"<p class='meta'>{e(describe_method(c))}; {len(c.measures.names)} statistics; false-alarm rate of the "
            f"whole comparison {ALPHA:g}; {c.wall_s:.1f} s on {e(c.where)}. Also as <a href='results.json'>results.json"
            f"</a>.</p>{particles}<h2>Frames</h2><table><tr><th>frame</th><th>step</th><th>phase</th>"
            "<th>ensemble spread</th><th>code's deviation</th><th>T² / limit</th><th>largest |z| / limit</th>"
            f"<th>verdict</th><th>statistics named</th></tr>{rows}</table><h2>Figures</h2><div class='figures'>"
            + "".join(figure_html(p.name, caption) for p, caption in figures) + "</div>")
    return page(f"mpmref compare: {c.scene.name}", body)


def write_report(comparison, out_dir):
    """Write every file of the report into ``out_dir`` (module docstring); returns the path of ``index.html``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures = [(deviation_figure(comparison, out / "deviation.png"), "particle distances and the round-off limit"),
               (test_figure(comparison, out / "test.png"), "each frame's tests against their limits")]
    figures += [(p, f"statistics of material {p.stem.split('_', 1)[1]}") for p in statistics_figures(comparison, out)]
    vtu = deviation_vtu(comparison, out)
    files = [p.name for p, _ in figures] + [vtu.name]
    write_text_atomic(out / "results.json", json.dumps(results(comparison, files), indent=1))
    write_text_atomic(out / "index.html", index_html(comparison, figures, vtu))
    return out / "index.html"
