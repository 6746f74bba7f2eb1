"""The checks, findings, tables and figures of the energy-ledger case (:mod:`verification.energy_ledger`), from the
result of :func:`~verification.energy_ledger.run`."""

from pathlib import Path

import numpy as np

from mpmref.observe.ledger import ASYNC_COLUMNS, ASYNC_TERMS

from ..framework.common import Check, Finding
from ..framework.page import Checks, Figure, Heading, Page, Table, Text, write_page
from ..framework.report import LEDGER_COLOURS, plot_ledger_areas, pyplot, save_figure, write_series
from .runs import run_scale, terms_of, total_energy

#: round-off of one energy, relative to the run's energy scale S (:func:`mpmref.observe.ledger.energy_scale`): each
#: energy is a float64 sum of N terms of one sign, in error by at most N u S (Higham 2002, §4.2; u = 1.1e-16), under
#: 1e-12 for the N <= 9000 particles or nodes of these runs
ROUNDOFF = 1e-12
#: the candidate's ledger against the reference's: the conformance bound (mpmref.conformance, the ledger stage)
CANDIDATE_BOUND = 1e-12
#: the friction block's boundary term against mu m g d
FRICTION_TOLERANCE = 0.05
#: the integration error summed over a fixed time: expected slope against Δt, and the tolerance on the fitted one
INTEGRATION_RATE, INTEGRATION_TOLERANCE = 1.0, 0.2


# ------------------------------------------------------------------------------------------- figures of merit
def steps_of(r):
    """Per step, each ledger column over the run's energy scale: (steps, columns), the differences of the
    cumulative ledger (also the synchronised intervals of an asynchronous run)."""
    return np.diff(r["ledger"], axis=0) / run_scale(r)


def largest(r, term):
    """The largest value a ``term`` took in one step of run ``r``, over the run's energy scale."""
    return float(steps_of(r)[:, ASYNC_COLUMNS.index(term)].max(initial=0.0))


def closure_error(r):
    r"""The largest gap between the sum of the cumulative terms and the change of total energy that the diagnostics
    measure, :math:`\max_k |\sum_t L_t(k) - (E_k - E_0)| / S`, over the sampled steps :math:`k`."""
    terms = r["ledger"][r["sampled_steps"]][:, [ASYNC_COLUMNS.index(t) for t in ASYNC_TERMS]].sum(axis=1)
    energy = total_energy(r)
    return float(np.max(np.abs(terms - (energy - energy[0])))) / run_scale(r)


def friction_ratio(f):
    r"""What the floor took over what friction's work :math:`\mu m g d` predicts, at the end of the slide."""
    return -f["boundary"][-1] / (f["mu"] * f["mass"] * f["g"] * f["distance"][-1])


def integration_slope(i):
    """The fitted slope of log(Σ|integration|) against log(Δt)."""
    return float(np.polyfit(np.log(i["dt"]), np.log(i["size"]), 1)[0])


# ---------------------------------------------------------------------------------------------- checks
def run_checks(r):
    """The checks of one run: the terms add up to the measured change, and each sign theory fixes for its scene."""
    name, n = r["key"], r["steps"]
    out = [Check(f"{name}: sum of the terms against the diagnostics' E(t) - E0, max / S", closure_error(r), "<=",
                 (n + 2) * ROUNDOFF, "the terms telescope to the change of total energy: round-off of each step's "
                 "energies and of the two diagnostics, (steps + 2) x 1e-12 of S")]
    if r["projection"]:
        out.append(Check(f"{name}: p2g_transfer in one step, max / S", largest(r, "p2g_transfer"), "<=", ROUNDOFF,
                         "P2G averages the particles' velocity fields at each node: by Cauchy-Schwarz the grid's "
                         "kinetic energy is at most the particles'"))
    if r["projection"] and not r["full_modes"]:
        out.append(Check(f"{name}: g2p_transfer in one step, max / S", largest(r, "g2p_transfer"), "<=", ROUNDOFF,
                         "G2P projects the grid's velocity onto the particle's field (its mean, and for APIC its "
                         "affine part) in the weights' norm: a projection never raises the energy"))
    if r["full_modes"]:
        g2p = float(np.abs(steps_of(r)[:, ASYNC_COLUMNS.index("g2p_transfer")]).max(initial=0.0))
        out.append(Check(f"{name}: |g2p_transfer| in one step, max / S", g2p, "<=", ROUNDOFF,
                         "PolyPIC's S^d modes represent any stencil velocity exactly (Fu et al. 2017 §5): G2P keeps "
                         "all of the grid's kinetic energy"))
    if r["static"]:
        out.append(Check(f"{name}: boundary in one step, max / S", largest(r, "boundary"), "<=", ROUNDOFF,
                         "a static wall's or collider's impulse does no positive work on the velocity it leaves "
                         "(talk Eq. 25), and -m|v - v~|^2/2 <= 0"))
    if r["plastic"]:
        out.append(Check(f"{name}: plastic in one step, max / S", largest(r, "plastic"), "<=", ROUNDOFF,
                         "the return maps lower the stored energy: sand's projects along the energy's gradient "
                         "(Klar et al. 2016); snow's clamp outweighs its hardening while xi J_P theta_c < "
                         "(1-theta_c)^2 (first order, uniform compression; docs/energy_ledger.md)"))
    return out


def checks(result):
    """Every run's checks (:func:`run_checks`), the friction block, the integration error's order, and the
    candidate's ledger against the reference's."""
    out = [c for r in result["runs"] for c in run_checks(r)]
    if result["friction"] is not None:  # None: not applicable to the backend
        out.append(Check("friction block: boundary / (mu m g d) - 1, magnitude",
                         abs(friction_ratio(result["friction"]) - 1.0),
                         "<=", FRICTION_TOLERANCE, "the floor's Coulomb friction mu m g does the work mu m g d over "
                         "the distance d the block slides: boundary books it"))
    if result["integration"] is not None:
        out.append(Check("integration: fitted slope of sum |integration| against dt, distance from 1",
                         abs(integration_slope(result["integration"]) - INTEGRATION_RATE), "<=",
                         INTEGRATION_TOLERANCE,
                         "symplectic Euler's energy error is O(dt^2) per step: summed to a fixed time, O(dt)"))
    for key, books in result["compared"].items():
        worst = max(books, key=lambda b: b["error"])
        out.append(Check(f"{key}: {result['candidate']} ledger against the reference's, max |a - r| / S "
                         f"({worst['worst']})", worst["error"], "<=", CANDIDATE_BOUND,
                         "the ledger reads stage outputs that agree to round-off: the conformance bound"))
    return out


def findings(result):
    """The terms whose sign theory leaves open that added energy over a run (beyond round-off of its scale)."""
    out = []
    for r in result["runs"]:
        signed = {"p2g_transfer", "g2p_transfer"} if r["projection"] else set()
        signed |= {"boundary"} if r["static"] else set()
        signed |= {"plastic"} if r["plastic"] else set()
        change = r["ledger"][-1, ASYNC_COLUMNS.index("energy_change")]
        for term in ASYNC_TERMS:
            value = r["ledger"][-1, ASYNC_COLUMNS.index(term)]
            if term not in signed and value > ROUNDOFF * run_scale(r):
                out.append(Finding(f"{r['key']}: {term} added energy over the run (J)", value,
                                   f"against the run's change of total energy {change:+.4g} J; theory fixes no sign "
                                   "for this term here"))
    return out


def _share(value, change):
    return f"{100.0 * value / change:+.0f} %" if change else "—"


# ---------------------------------------------------------------------------------------------- tables
def split_rows(result):
    """One row per run: its set-up, its wall time (the steps, without the candidate's), the measured change of total
    energy and each ledger column's cumulative joules."""
    rows = []
    for r in result["runs"]:
        energy, last = total_energy(r), r["ledger"][-1]
        rows.append({"run": r["key"], "method": r["method"], "particles": int(r["n_particles"]),
                     "steps": int(r["steps"]), "t_end": float(r["t"][-1]), "wall_s": float(r["wall_s"]),
                     "E0": float(energy[0]), "measured_change": float(energy[-1] - energy[0]),
                     **{c: float(last[ASYNC_COLUMNS.index(c)]) for c in ASYNC_COLUMNS}})
    return rows


def tables(result):
    """The tables of ``results.json``: each run's split of its energy change (``split``), the candidate's ledger
    against the reference's (``candidate``), the friction block and the integration study."""
    f, i = result["friction"], result["integration"]
    return {"split": split_rows(result),
            "candidate": [{"run": key, "state": state, "error": b["error"], "worst": b["worst"]}
                          for key, books in result["compared"].items() for state, b in zip(("half-way", "end"), books)],
            "friction": [{"mu": f["mu"], "mass": f["mass"], "g": f["g"], "distance": float(f["distance"][-1]),
                          "boundary": float(f["boundary"][-1]), "ratio": float(friction_ratio(f))}] if f else [],
            "integration": [{"dt": float(dt), "sum_abs_integration": float(s)}
                            for dt, s in zip(i["dt"], i["size"])] if i else []}


def split_table(result):
    """The split table of the page: joules, and each term's share of the measured change."""
    header = ("run", "method", "particles", "steps", "t_end [s]", "E0 [J]", "ΔE [J]", *ASYNC_TERMS, "closure [J]")
    rows = []
    for row in split_rows(result):
        change = row["measured_change"]
        cells = [f"{row[t]:.4g} ({_share(row[t], change)})" if row[t] else "0" for t in ASYNC_TERMS]
        rows.append((row["run"], row["method"], row["particles"], row["steps"], f"{row['t_end']:.4g}",
                     f"{row['E0']:.6g}", f"{change:.4g}", *cells, f"{row['closure']:.1e}"))
    return Table(header, tuple(rows))


# --------------------------------------------------------------------------------------------- figures
#: the width of a figure (inches, at the reports' 110 dpi): about the 600 pixels a figure gets on a report's page, so
#: that its text reads at about its point size
WIDTH = 6.6
#: the runs drawn in one figure of the terms over time (two columns of panels)
PANELS = 6


def plot_split(result, path):
    """The case's main figure: one bar per run, its terms at the end as shares of the energy the run's stages moved
    (:math:`\\sum_t |L_t|`), those that took energy to the left, those that added it to the right, and the net
    change as a black diamond; each run's change of total energy in joules and against :math:`E_0` beside it."""
    rows = split_rows(result)
    terms = [t for t in ASYNC_TERMS if any(row[t] for row in rows)]
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(WIDTH, 1.4 + 0.42 * len(rows)), layout="constrained")
    for y, row in enumerate(rows):
        moved = sum(abs(row[t]) for t in terms) or 1.0
        left = right = 0.0
        for term in terms:
            share = row[term] / moved
            start = right if share > 0 else left
            ax.barh(y, share, left=start, color=LEDGER_COLOURS[term], height=0.7, label=term)
            right, left = (right + share, left) if share > 0 else (right, left + share)
        ax.plot(row["measured_change"] / moved, y, "kD", ms=5, label="net change E(t_end) - E0")
        ax.text(1.04, y, f"{row['measured_change']:+.3g} J ({100 * row['measured_change'] / row['E0']:+.2g} % of E0)",
                va="center", fontsize=8, transform=ax.get_yaxis_transform())
    ax.set_yticks(range(len(rows)), [f"{row['run']} ({row['method']})" for row in rows], fontsize=8.5)
    ax.invert_yaxis()
    ax.set_xlim(-1.0, 1.0)
    ax.axvline(0.0, color="k", lw=0.6)
    ax.set_xlabel("share of the energy the stages moved: taken (left), added (right)")
    ax.grid(True, axis="x", alpha=0.3)
    handles = dict(zip(*reversed(ax.get_legend_handles_labels())))
    handles["net change E(t_end) - E0"] = handles.pop("net change E(t_end) - E0")          # the diamond last
    fig.legend(handles.values(), handles.keys(), loc="outside upper center", ncol=4, fontsize=8)
    return save_figure(fig, path, caption=(
        "Where each run's energy went, at the end of the run: the ledger's terms as shares of the energy its stages "
        "moved (the sum of their sizes), those that took energy to the left of zero and those that added it to the "
        "right, with the net change of total energy as a black diamond and, beside each bar, that change in joules "
        "and against the initial energy. Look for the transfers (P2G blue, G2P orange) taking energy in every run but "
        "FLIP's, whose G2P gives back part of what its P2G took, and CPIC's cut2d, whose ghost velocities make its "
        "G2P add energy; PolyPIC's G2P absent; the walls (brown) taking energy at contact; plasticity (red) "
        "dissipating in snow88 and sand, where the integrator (green) adds energy; and in the asynchronous stork the "
        "exchange across its level interfaces (olive). The checks hold the signs; the runs' terms over time are in "
        "the figures that follow."))


def plot_terms(result, folder):
    """The runs' cumulative terms over time, :data:`PANELS` runs a figure in two columns of panels
    (:func:`~verification.framework.report.plot_ledger_areas`): ``ledger_time_1.png``, ... in ``folder``."""
    runs = result["runs"]
    return [_terms_figure(runs[i:i + PANELS], Path(folder) / f"ledger_time_{i // PANELS + 1}.png")
            for i in range(0, len(runs), PANELS)]


def _terms_figure(runs, path):
    plt = pyplot()
    rows = -(-len(runs) // 2)
    fig, axes = plt.subplots(rows, 2, figsize=(WIDTH, 0.9 + 2.3 * rows), squeeze=False, layout="constrained")
    for ax, r in zip(axes.flat, runs):
        plot_ledger_areas(ax, r["t"], terms_of(r), r["ledger"][:, ASYNC_COLUMNS.index("energy_change")])
        ax.plot(r["t"][r["sampled_steps"]], total_energy(r) - total_energy(r)[0], "wo", ms=3.5, mec="k",
                label="diagnostics' E - E0")
        ax.set_title(f"{r['key']} ({r['method']})", fontsize=9)
        ax.tick_params(labelsize=8)
        ax.locator_params(axis="x", nbins=4)
        ax.grid(True, alpha=0.3)
    for ax in axes.flat[len(runs):]:
        ax.set_visible(False)
    handles = {label: h for ax in axes.flat for h, label in zip(*ax.get_legend_handles_labels())}
    fig.legend(handles.values(), handles.keys(), loc="outside upper center", ncol=3, fontsize=8)
    fig.supxlabel("time [s]", fontsize=9)
    fig.supylabel("cumulative energy [J]", fontsize=9)
    names = ", ".join(r["key"] for r in runs)
    return save_figure(fig, path, caption=(
        f"Where the energy of {names} went over time: the ledger's cumulative terms stacked above zero (energy a "
        "stage added) and below (energy it took), in joules against time, with the change of total energy in black "
        "(their sum) and the diagnostics' own measurement of it as dots on the line. Look for when each term grows: "
        "the transfers at every step, the walls at contact, plasticity as the material yields."))


def plot_friction(result, path):
    r"""What the floor took, -boundary, against :math:`\mu m g d` as the block slides."""
    f = result["friction"]
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(f["t"], -f["boundary"], label="-boundary (ledger)")
    ax.plot(f["t"], f["mu"] * f["mass"] * f["g"] * f["distance"], "k--", label="mu m g d (friction's work)")
    ax.set(xlabel="time [s]", ylabel="energy [J]", title="friction block: what the floor took")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path, caption=(
        "A block sliding on a floor with Coulomb friction mu = 0.3: the energy the ledger books to the boundary "
        "against the work mu m g d of the friction force over the distance slid. Look for the two curves together "
        "once the block has settled on the floor (checked at the end: within 5 %)."))


def plot_integration(result, path):
    """The summed size of the integration term against Δt, with the fitted slope."""
    i = result["integration"]
    slope = integration_slope(i)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(i["dt"], i["size"], "o-", label=f"sum |integration| (fitted slope {slope:.3f})")
    ax.loglog(i["dt"], i["size"][0] * i["dt"] / i["dt"][0], "k--", label="slope 1")
    ax.set(xlabel="dt [s]", ylabel="sum over the steps of |integration| [J]",
           title="the integration error to a fixed time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path, caption=(
        "The energy case's oscillating jelly (MLS-MPM) to a fixed time at dt, dt/2, ...: the sum over the steps of "
        "the size of the ledger's integration term. Look for a line parallel to the dashed slope 1: symplectic "
        "Euler's error is O(dt^2) per step, O(dt) over a fixed time (checked: slope within 0.2 of 1)."))


# ---------------------------------------------------------------------------------------------- report
def candidate_table(result):
    """The table of the candidate's ledger against the reference's, per run and state."""
    return Table(("run", "state", "max abs(a - r) / S", "worst term"),
                 tuple((row["run"], row["state"], f"{row['error']:.2e}", row["worst"])
                       for row in tables(result)["candidate"]))


def report(result, out_dir):
    """Write the figures, each run's VTK series (``vtk/<run>/particles.pvd``, with the per-particle terms) and
    ``energy_ledger.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    terms = plot_terms(result, out) if result["runs"] else []
    paths = [plot_split(result, out / "ledger_terms.png"), *terms] if result["runs"] else []
    paths += [plot_friction(result, out / "friction.png")] if result["friction"] else []
    paths += [plot_integration(result, out / "integration_order.png")] if result["integration"] else []
    paths += [write_series(out / "vtk" / r["key"], r["frames"]) for r in result["runs"]]
    f = (tables(result)["friction"] or [None])[0]
    sliding = ([Text(f"The sliding block: d = {f['distance']:.4g} m, boundary = {f['boundary']:.4g} J, -boundary / "
                     f"(mu m g d) = {f['ratio']:.4f}."), Figure("friction.png", "friction")] if f else
               [Text("The sliding block: not applicable.")])
    page = Page("Where the energy goes, run by run", [
        Text("Each run's change of total energy split into the ledger's terms (joules; in brackets, the share of the "
             "measured change ΔE; `closure` is the round-off of the terms' sum against the ledger's own ΔE)."),
        split_table(result), Figure("ledger_terms.png", "terms"), *(Figure(p.name, "terms over time") for p in terms),
        Heading(f"The candidate's ledger ({result['candidate']}) against the reference's"),
        Text("One step booked on both from the same state, half-way through the run and at its end."),
        candidate_table(result), Heading("Friction and the integration error"), *sliding,
        Figure("integration_order.png", "integration") if result["integration"] else
        Text("The integration error's order: not applicable."), Heading("Checks"), Checks(checks(result))])
    return paths + [write_page(page, out / "energy_ledger.md")]
