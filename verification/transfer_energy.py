r"""Transfer-only energy study: repeated P2G → G2P with Δt = 0 on a random smooth velocity field.

With :math:`\Delta t = 0` nothing moves and no force acts, so every change of kinetic energy is the
transfers' own dissipation. The energy counted on the particles includes what APIC and PolyPIC carry in
their affine and higher modes (:func:`mpmref.observe.diagnostics.diagnostics`: ``kinetic + kinetic_affine +
kinetic_modes``). Theory (Jiang et al. 2015 §6; Fu et al. 2017 §5):

* PIC averages the field twice per cycle, so it loses energy every cycle, more at short wavelengths;
* APIC keeps the affine part of the local field and loses less;
* FLIP with :math:`\alpha = 1` adds the (zero) grid change to the particle velocity and keeps it exactly;
* full-mode PolyPIC (:math:`S^d` modes) represents every stencil velocity exactly: it loses energy only
  in the first cycle (projecting particles' fields onto the grid) and is then a fixed point.

The MLS-MPM transfer is APIC's, so it is not listed separately.

On a backend that implements a part (:mod:`verification.framework.applicable`): with :math:`\Delta t = 0` no stress
acts, so the material may be any the backend has, and the open walls its walls on a padded domain (nothing reaches
them). Each check runs when the backend has every scheme it compares (PIC, FLIP(1), APIC, PolyPIC); the others are not
applicable, and a scheme runs only if a check that applies needs it.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpmref import SceneBuilder, Simulation
from mpmref.steppers import substep

from .framework.applicable import Allow, Triage, fit
from .framework.case import VerificationCase
from .framework.common import Check
from .framework.page import Checks, Figure, Page, Table, write_page
from .framework.report import pyplot, save_figure

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "transfer_energy.png"

SCHEMES = (("pic", {}), ("flip", {"flip_alpha": 1.0}), ("apic", {}), ("polypic", {}))
#: what the claims let a backend that implements a part change (module docstring)
ALLOWS = Allow(materials="substitute", walls="open")


@dataclass(frozen=True)
class Params:
    dim: int = 2
    cells: int = 32
    kernel: str = "quadratic"
    wavelengths: tuple = (8.0, 3.0)  # in cells
    cycles: int = 10
    ppc: int = 4
    n_waves: int = 6
    seed: int = 2017

    @classmethod
    def quick(cls):
        return cls(cells=24, cycles=6)

    @classmethod
    def full(cls):
        return cls(cells=64, cycles=20, wavelengths=(16.0, 8.0, 4.0, 3.0, 2.5))


def smooth_field(x, wavelength, n_waves, rng):
    """Sum of ``n_waves`` plane waves of the given wavelength, random directions, phases and polarisations."""
    d = x.shape[1]
    v = np.zeros_like(x)
    for _ in range(n_waves):
        direction = rng.standard_normal(d)
        direction /= np.linalg.norm(direction)
        amplitude = rng.standard_normal(d)
        v += np.cos(2 * np.pi / wavelength * x @ direction + rng.uniform(0, 2 * np.pi))[:, None] * amplitude
    return v


def _scene(params, scheme, options):
    dim = params.dim
    return (SceneBuilder(dim=dim, name="transfer_energy").grid(size=1.0, cells=params.cells)
            .method(scheme, kernel=params.kernel, **options)
            .material("m", "fixed_corotated", E=1.0, nu=0.3, rho=1.0)
            .box("m", lower=[0.25] * dim, upper=[0.75] * dim, ppc=params.ppc, sampling="jittered", seed=params.seed)
            .walls("open").time(dt=1.0, steps=params.cycles).build())  # unused: each cycle is a Δt = 0 substep


def particle_kinetic_energy(sim):
    d = sim.diagnostics()
    return d["kinetic"] + d["kinetic_affine"] + d["kinetic_modes"]


def energy_history(params, scheme, options, wavelength, backend="numpy"):
    """Particle kinetic energy before and after each Δt = 0 transfer cycle, and the final velocities."""
    sim = Simulation(fit(_scene(params, scheme, options), backend, ALLOWS).scene, backend=backend)
    rng = np.random.default_rng(params.seed)
    sim.v = smooth_field(sim.x, wavelength * sim.scene.grid.dx, params.n_waves, rng)
    history, velocities = [particle_kinetic_energy(sim)], []
    for _ in range(params.cycles):  # a transfer cycle, not a time step: P2G, grid update with Δt = 0, G2P
        sim.particles = substep(sim.backend, sim.particles, 0.0, sim.time)
        history.append(particle_kinetic_energy(sim))
        velocities.append(sim.v.copy())
    return np.array(history), velocities


def run(params=Params(), backend="numpy", executor=None):
    """Energy kept per scheme and wavelength: first cycle, per cycle after, and the fixed-point residual (in
    this process: the runs are short, ``executor`` is not used), for the schemes of the checks that apply to the
    backend; the other checks are listed as not applicable."""
    triage = Triage(backend)
    for scheme, options in SCHEMES:
        triage.fit(scheme, _scene(params, scheme, options), ALLOWS)
    needed = set()
    for name, schemes, _ in claims(params):
        lacking = [reason for scheme in schemes for reason in triage.reasons(scheme)]
        if lacking:
            triage.skip(name, lacking)
        else:
            needed |= set(schemes)
    if not needed:
        raise triage.nothing_ran()
    rows = []
    for scheme, options in SCHEMES:
        if scheme not in needed:
            continue
        for wl in params.wavelengths:
            e, vel = energy_history(params, scheme, options, wl, backend)
            later = e[2:] / e[1:-1]
            rows.append({
                "scheme": scheme + ("(α=1)" if scheme == "flip" else ""), "wavelength_cells": wl,
                "kept_first": e[1] / e[0], "kept_per_cycle": (e[-1] / e[1]) ** (1.0 / (len(e) - 2)),
                "max_cycle_change_after_first": float(np.max(np.abs(later - 1.0))),
                "kept_each_cycle_max": float(np.max(e[1:] / e[:-1])),
                "velocity_change_after_first": float(np.max(np.abs(vel[-1] - vel[0])) / np.max(np.abs(vel[0]))),
                "kept": (e / e[0]).tolist(),
            })
    return {"params": params, "rows": rows, **triage.record()}


def _row(rows, scheme, wl):
    return next(r for r in rows if r["scheme"].startswith(scheme) and r["wavelength_cells"] == wl)


def claims(params):
    """Theory's claims (module docstring): ``(name, schemes it compares, check(rows) -> Check)`` each."""
    wls = sorted(params.wavelengths, reverse=True)
    long_wl, short_wl = wls[0], wls[-1]
    out = []
    for wl in wls:
        out += [
            (f"PIC loses energy in every cycle (λ = {wl} Δx)", ("pic",),
             lambda rows, wl=wl: (_row(rows, "pic", wl)["kept_each_cycle_max"], "<", 1.0,
                                  "double averaging is a strict contraction of non-affine fields")),
            (f"APIC keeps more per cycle than PIC (λ = {wl} Δx)", ("pic", "apic"),
             lambda rows, wl=wl: (_row(rows, "apic", wl)["kept_per_cycle"] - _row(rows, "pic", wl)["kept_per_cycle"],
                                  ">", 0.0, "APIC also transfers the local affine part")),
            (f"FLIP(α=1) energy change (λ = {wl} Δx)", ("flip",),
             lambda rows, wl=wl: (abs(_row(rows, "flip", wl)["kept_first"] - 1.0)
                                  + _row(rows, "flip", wl)["max_cycle_change_after_first"], "<=", 1e-13,
                                  "v_p + Σ w (v_i - ṽ_i) with v_i = ṽ_i leaves v_p unchanged; round-off only")),
            (f"PolyPIC first-cycle loss (λ = {wl} Δx)", ("polypic",),
             lambda rows, wl=wl: (1.0 - _row(rows, "polypic", wl)["kept_first"], ">", 1e-6,
                                  "projecting overlapping particle fields onto one grid field loses energy once")),
            (f"PolyPIC change per cycle after the first (λ = {wl} Δx)", ("polypic",),
             lambda rows, wl=wl: (_row(rows, "polypic", wl)["max_cycle_change_after_first"], "<=", 1e-12,
                                  "all S^d modes reproduce the stencil velocities: a fixed point")),
        ]
    out.append((f"PIC loses more at λ = {short_wl} Δx than at {long_wl} Δx", ("pic",),
                lambda rows: (_row(rows, "pic", long_wl)["kept_per_cycle"] - _row(rows, "pic", short_wl)[
                    "kept_per_cycle"], ">", 0.0,
                    "B-spline smoothing damps short wavelengths more (its symbol decreases with wavenumber)")))
    return out


def checks(result):
    """Theory's claims as checks with bounds (see the module docstring): those whose schemes ran."""
    ran = {r["scheme"].split("(")[0] for r in result["rows"]}
    return [Check(name, *check(result["rows"])) for name, schemes, check in claims(result["params"])
            if set(schemes) <= ran]


def table(result):
    """The page's table: per scheme and wavelength, the energy kept in the first cycle and after."""
    header = ("scheme", "λ / Δx", "kept in cycle 1", "kept per cycle after", "max change per cycle after 1")
    return Table(header, tuple((r["scheme"], f"{r['wavelength_cells']:g}", f"{r['kept_first']:.6f}",
                                f"{r['kept_per_cycle']:.6f}", f"{r['max_cycle_change_after_first']:.2e}")
                               for r in result["rows"]))


def plot_energy(result, path):
    """Kinetic energy kept against the transfer cycle, one panel per wavelength, one line per scheme."""
    wavelengths = sorted(result["params"].wavelengths, reverse=True)
    plt = pyplot()
    fig, axes = plt.subplots(1, len(wavelengths), figsize=(4.2 * len(wavelengths), 3.8), sharey=True, squeeze=False)
    for ax, wl in zip(axes[0], wavelengths):
        for row in (r for r in result["rows"] if r["wavelength_cells"] == wl):
            ax.plot(np.arange(len(row["kept"])), row["kept"], marker="o", ms=3, label=row["scheme"])
        ax.set(title=f"λ = {wl:g} Δx", xlabel="P2G → G2P cycles (Δt = 0)")
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("particle kinetic energy / E0")
    axes[0][-1].legend(fontsize=8)
    return save_figure(fig, path, caption=(
        "Particle kinetic energy (affine and PolyPIC modes included) after each Δt = 0 transfer cycle, over its "
        "start. Look for PIC falling every cycle and faster at the shorter wavelength, APIC above it, FLIP(α=1) "
        "flat at 1, and PolyPIC dropping in the first cycle only, then flat (each checked)."))


def report(result, out_dir):
    """Write the energy plot and ``transfer_energy.md`` with the table and the checks."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figure = plot_energy(result, out / "transfer_energy.png")
    page = Page("Transfer-only energy study",
                [table(result), Checks(checks(result)), Figure("transfer_energy.png", "energy")])
    return [figure, write_page(page, out / "transfer_energy.md")]


#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, main_figure=MAIN_FIGURE)
