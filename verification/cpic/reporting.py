"""The checks, findings, figures and tables of the CPIC case (:mod:`verification.cpic`), from its
:class:`~verification.cpic.results.CpicResult`.
"""

from pathlib import Path

import numpy as np

from mpmref.io.vtk import write_polylines_vtp
from mpmref.physics.cdf import PENALTY_WINDOW
from mpmref.rigid.trimesh import TriMesh

from ..framework.common import Check, Finding
from ..framework.page import Checks, Figure, Heading, Items, Page, Table, Text, write_page
from ..framework.report import pyplot, save_figure, write_series
from .scenes import fixed_dt


def checks(result):
    """The case's checks: no crossing, the hard impact, momentum and two-way coupling, the cuts, friction, and the
    sand wheel (:func:`wheel_checks`)."""
    ex, cut, fr = result.exact, result.cut, result.friction
    out = [Check("no crossing: jelly onto a fixed segment, particles that crossed", result.drop.crossings, "<=", 0,
                 "sticky side tags and compatible transfers: no particle changes side of a body"),
           Check("no crossing: blade through sand at 1 m/s, particles that crossed", result.sand.crossings, "<=", 0,
                 "as above, for a moving blade"),
           Check(f"hard impact at {result.params.impact_speed:g} m/s: particles on the far side at the end",
                 result.impact.far_side, "<=", 0, "sticky side tags: a particle pushed across is seen as having "
                 "penetrated and is pushed back, never joins the other side"),
           Check("momentum: exact variant, max |P_particles + P_plate - P_0| / (m_ball |v|)", ex.drift, "<=", 1e-12,
                 "what the particle keeps at an incompatible node plus what the plate receives is its momentum there; "
                 "internal forces sum to zero: round-off only"),
           Check("two-way: plate velocity along the ball's velocity (m/s)", -ex.plate_v, ">", 0.0,
                 "the plate receives the momentum the ball could not give the grid beyond it"),
           Check("cutting: connected components after the wedge blade", cut.components, ">=", 2,
                 "the blade splits the block: material on its two faces exchanges nothing"),
           Check("cutting: connected components after the wedge blade (at most)", cut.components, "<=", 2,
                 "one cut gives two pieces, no debris"),
           Check("cutting: particles on the far side of the blade at the end", cut.far_side, "<=", 0,
                 "sticky side tags: the pieces stay on their faces (per-step crossings are in the table)"),
           Check("friction: |stopping distance / (v^2 / 2 mu g) - 1|",
                 abs(fr.distance / fr.expected - 1.0) if fr.stopped else float("inf"), "<=", 0.15,
                 "Coulomb friction decelerates the block at mu g (acceptance: within 15 %)")]
    return out + _cut3d_checks(result.cut3d) + wheel_checks(result.wheel)


def _cut3d_checks(cut):
    """The 3D cut's checks: four pieces, no crossing."""
    return [Check("3D cutting: connected components after the crossed blades", cut.components, ">=", 4,
                  "two crossed blades split the block into four: material on the faces of a blade exchanges nothing"),
            Check("3D cutting: connected components after the crossed blades (at most)", cut.components, "<=", 4,
                  "two cuts give four pieces, no debris"),
            Check("3D cutting: particles that crossed a blade (any step)", cut.crossings, "<=", 0,
                  "sticky side tags and compatible transfers: no particle changes side of a triangle it projects on")]


def wheel_checks(w):
    """The sand wheel's checks: a steady-signed, nonzero angular velocity, and no sand deeper inside the ring than
    the penalty window's far edge (the sand inside the ring by any margin is an open finding,
    :func:`_wheel_findings`)."""
    return [Check(f"sand wheel: min of sign(omega_end) omega over the last half ({w.t_end / 2:g} s ..) (rad/s)",
                  w.late_min, ">=", w.floor,
                  "the sand turns the wheel one way: omega keeps the sign it ends with over the last half of the run "
                  "and stays above a tenth of the rate omega* = m_dot |v| R / (c I) at which the stream's momentum "
                  "would balance the damping"),
            Check("sand wheel: deepest sand inside the ring, any step (dx)", w.depth_max, "<=", -PENALTY_WINDOW[0],
                  "no sand passes through the ring: a particle past its line by less than the penalty window's far "
                  "edge (0.3 dx) is held by its kept tag and pushed back by the penalty; the per-body fit gives it "
                  "the ring's own distance and normal in the corners where blades meet the ring")]


def findings(result):
    """What the case reports, not judges: crossings undone, the default variant's momentum, the collision's energy,
    the stopping distance, the reference code's variants (default and full presets) and the sand wheel."""
    d, ex = result.default, result.exact
    return [
        Finding(f"hard impact at {result.params.impact_speed:g} m/s: particles that crossed for a while",
                result.impact.crossings,
                "crossings undone within the run: nothing on the grid stops a fast particle, only its ghost "
                "velocities, the pushing force and the penalty; its kept side tag brings it back."),
        Finding("momentum: default variant, max |P_particles + P_plate - P_0| / (m_ball |v|)", d.drift,
                "the plate's velocity changes between P2G (impulses computed with the old one) and G2P (ghost "
                "velocities with the new one), so what the plate receives and what the ball keeps no longer add up."),
        Finding("collision: (kinetic + elastic + plate kinetic energy) at the end / at the start",
                ex.energy_end / ex.energy0,
                "the contact is partly inelastic: at incompatible nodes the friction projection removes the ball's "
                "approach velocity relative to the plate, which G2P does not give back (PIC also damps)."),

        Finding("friction: stopping distance (m)", result.friction.distance,
                f"expected v^2/(2 mu g) = {result.friction.expected:.4f} m; stopped at t = "
                f"{result.friction.stop_time:.3f} s (expected "
                f"{1 / (result.params.mu * result.params.g):.3f} s)."),
    ] + _reference_ghosts(result) + _rotor(result) + _reference_push(result) + \
        _wheel_findings(result.wheel)


def _wheel_findings(w):
    """The sand wheel's findings: sand inside the ring by any margin (open), its angular velocity, crossings."""
    h = w.history
    return [Finding("sand wheel (open: the acceptance asks for 0): sand particles found inside the ring by any margin",
                    w.entered, f"most inside at one step {w.inside_max}, deepest {w.depth_max:.3f} dx; every "
                    f"one was within {w.entry_blade_distance:.2f} dx of a blade when first found inside: sand "
                    "resting on the ring is pushed toward it by the pile through its compatible nodes, which nothing "
                    "on the grid stops, and creeps past the ring's line by a fraction of a cell before the penalty "
                    "(from 0.05 dx past the line) pushes it back (docs/cpic.md, \"The sand wheel\")."),
            Finding("sand wheel: angular velocity at the end (rad/s)", w.omega_end,
                    f"positive is counter-clockwise; floor of the check {w.floor:.3g} rad/s (omega*/10); "
                    f"{int(h[-1, 3])} sand particles at {h[-1, 0]:.2f} s."),
            Finding("sand wheel: particles that crossed a segment of the wheel or the floor (any step)",
                    w.crossings, "blades sweeping through sand push it only through ghost velocities and the "
                    "penalty (no pushing force, as in the reference scene), so grazing particles cross a blade's line "
                    "by a fraction of a cell before their kept tag brings them back (the ring: the finding above).")]


def _reference_push(result):
    """The sand blade with the reference's default pushing force (default and full presets)."""
    run = result.sand_2e4
    if run is None:
        return []
    return [Finding("blade through sand, pushing force 2e4: particles that crossed (any step)", run.crossings,
                    "with the reference code's default pushing force, a near particle's ghost velocities get "
                    f"f_push dt dx = {2e4 * fixed_dt(result.params, 3e4, 1000.0) / result.params.cells:.2f} m/s at "
                    f"{result.params.cells} cells; the blade, moving at {result.params.blade_speed:g} m/s, "
                    "overtakes grazing particles before the penalty (which starts at 0.05 dx) acts.")]


def _rotor(result):
    """The spinning plate (default and full presets)."""
    rotor = result.rotor
    if rotor is None:
        return []
    return [Finding("rotor: particles that crossed the spinning plate (any step)", rotor.crossings,
                    f"of {rotor.n_particles}: a plate sweeping through material pushes it only through ghost "
                    "velocities, the pushing force and the penalty, so grazing particles cross its line by a fraction "
                    "of a cell before their kept tag brings them back (the far-side count means nothing for a plate "
                    "that turns half a revolution).")]


def _reference_ghosts(result):
    """The collision and the friction run with the reference code's ghost velocities (default and full presets)."""
    if result.friction_reference is None:
        return []
    ball = result.exact_reference
    ref, p = result.friction_reference, result.params
    c = ref.com
    decel = (c[0, 3] - c[-1, 3]) / (c[-1, 0] - c[0, 0])
    return [Finding("collision, reference ghosts (method.ghost_force = false): energy at the end / at the start",
                    ball.energy_end / ball.energy0,
                    "energy is created: the compressed ball's stress at incompatible nodes keeps pushing the plate "
                    "while the ghost velocities (its own velocity, once separating) hold the ball's surface "
                    "compressed, so the plate leaves faster than any elastic collision allows. Momentum stays exact "
                    f"(drift {ball.drift:.1e})."),
            Finding("friction, reference ghosts (method.ghost_force = false): effective mu", decel / p.g,
                    f"measured deceleration / g over {c[-1, 0]:.2f} s (mu = {p.mu:g} declared): the projection sees "
                    "only the particles' own approach velocity, while a resting block's weight reaches the segment "
                    "through its stress at incompatible nodes, which no friction acts on.")]


def backends_run(result, backend):
    """The backend every run used (the one asked for)."""
    return [result.backend]


def _momentum_plot(result, path):
    """The collision's vertical momentum of ball, plate and both, for the exact and the default variant."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for key, run, style in (("exact", result.exact, "-"), ("default", result.default, "--")):
        h = run.history
        ax.plot(h[:, 0], h[:, 2] / run.p0, "C0" + style, label=f"ball, {key}")
        ax.plot(h[:, 0], h[:, 4] / run.p0, "C1" + style, label=f"plate, {key}")
        ax.plot(h[:, 0], (h[:, 2] + h[:, 4]) / run.p0, "k" + style, label=f"total, {key}")
    ax.set(xlabel="time [s]", ylabel="P_y / (m_ball |v|)", title="ball onto a free plate: vertical momentum")
    ax.legend(fontsize=7)
    save_figure(fig, path, caption="Vertical momentum of the ball, the plate and their sum, relative to the ball's "
                "initial momentum, for the exact and the default variant: the sum stays flat (exact to round-off).")
    return path


def _friction_plot(result, path):
    """The sliding block's velocity against Coulomb friction's 1 - mu g t."""
    plt = pyplot()
    fr = result.friction
    c = fr.com
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(c[:, 0], c[:, 3], "C0-", label="CPIC block")
    t = c[:, 0]
    p = result.params
    ax.plot(t, np.maximum(1.0 - p.mu * p.g * t, 0.0), "k--", label="1 - mu g t")
    ax.set(xlabel="time [s]", ylabel="v_x of the centre of mass [m/s]", title="block sliding on a segment")
    ax.legend()
    save_figure(fig, path, caption="The sliding block's velocity against Coulomb friction's 1 - mu g t.")
    return path


def _wheel_plot(result, path):
    """The sand wheel's angular velocity, the check's floor and the judged half of the run."""
    w = result.wheel
    h, sign = w.history, np.sign(w.omega_end) or 1.0
    fig, ax = pyplot().subplots(figsize=(6, 3.5))
    ax.plot(h[:, 0], h[:, 1], "C0-", label="omega of the wheel")
    ax.axhline(sign * w.floor, color="k", ls="--", lw=0.8, label="floor (omega*/10)")
    ax.axvspan(0.5 * w.t_end, w.t_end, color="0.9", label="last half (judged)")
    ax.set(xlabel="time [s]", ylabel="angular velocity [rad/s]", title="sand wheel")
    ax.legend(fontsize=7)
    save_figure(fig, path, caption="The sand wheel's angular velocity: it must keep its sign and stay beyond the "
                "floor over the last half of the run (shaded).")
    return path


def table(result):
    """The table of the crossings of every run but the sand wheel and the baselines (its footnote: :data:`FAR_SIDE`)."""
    rows = []
    for name, r in (("jelly onto a segment", result.drop), ("blade through sand", result.sand),
                    *((("blade through sand, f_push 2e4", result.sand_2e4),) if result.sand_2e4 is not None else ()),
                    ("hard impact", result.impact),
                    ("ball onto a free plate (exact)", result.exact),
                    ("ball onto a free plate (default)", result.default),
                    ("jelly onto a wedge blade", result.cut),
                    ("3D: jelly onto two crossed wedge blades", result.cut3d),
                    ("block sliding (friction)", result.friction)):
        rows.append((name, r.n_particles, r.steps, r.crossings, r.far_side))
    return Table(("run", "particles", "steps", "crossings (per step)", "on the far side at the end*"), tuple(rows))


#: the footnote of :func:`table`'s last column
FAR_SIDE = ("*side at the end against side at the start, for particles projecting onto a segment both times: for the "
            "moving blade it also counts sand that flowed under the blade's lower end, which is inside the layer.")


def baseline_table(result):
    """The table of the baselines: crossings, mass lost and connected components."""
    rows = []
    for r in result.baselines:
        name = {"cpic": "CPIC blade (zero thickness)", "level_set": "level-set blade (box, 0.5 dx thick)",
                "remove": f"removing the particles within {r.width:g} dx", "soften": f"softening {r.width:g} dx "
                "(E x 1e-4)"}[r.kind]
        rows.append((name, r.crossings, f"{r.mass_lost:.2%}", r.components))
    return Table(("cut by", "particles crossing the line", "mass lost", "connected components"), tuple(rows))


def report(result, out_dir):
    """Plots, the VTK series of each run with its bodies' final pose (``rigid_bodies_end.vtp``), and ``cpic.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [_momentum_plot(result, out / "momentum.png"), _friction_plot(result, out / "friction.png"),
             _wheel_plot(result, out / "wheel.png")]
    runs = {"drop": result.drop, "sand": result.sand, "impact": result.impact,
            **({"sand_2e4": result.sand_2e4} if result.sand_2e4 is not None else {}),
            "ball": result.exact, "wheel": result.wheel,
            **({"rotor": result.rotor} if result.rotor is not None else {}), "cut": result.cut, "cut3d": result.cut3d,
            "friction": result.friction}
    for key, r in runs.items():
        paths.append(write_series(out / "vtk" / key, r.frames))
        paths.append(out / "vtk" / key / "rigid_bodies_end.vtp")  # the bodies where the run ends
        write_polylines_vtp(paths[-1], [(b.vertices, b.triangles if isinstance(b, TriMesh) else b.segments)
                                        for b in r.bodies])
    page = Page(f"CPIC (backend {result.backend})", [table(result), Text(FAR_SIDE)])
    if result.baselines:
        page.add(Heading("Baselines: the same block over a vertical cut line"), baseline_table(result))
    page.add(Figure("momentum.png", "momentum"), Figure("friction.png", "friction"), Figure("wheel.png", "sand wheel"),
             Heading("Findings"), Items(tuple(f"{f.name}: {f.value:.3g}. {f.sentence}" for f in findings(result))),
             Heading("Checks"), Checks(checks(result)))
    return paths + [write_page(page, out / "cpic.md")]
