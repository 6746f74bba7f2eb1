"""The energy ledger (mpmref/observe/ledger.py): each term against its sign from theory or an independent figure.

Scenes are small (NumPy reference, 24-32 cells). ``E0`` below is the run's initial total energy; "round-off"
is 1e-12 of it.
"""

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mpmref import Scene, SceneBuilder, SceneError, Simulation
from mpmref.observe.ledger import COLUMNS, TERMS, EnergyLedger
from mpmref.steppers.pipeline import substep
from verification.energy import Params, make_simulation
from verification.energy_ledger import runs as ledger_runs
from verification.momentum import VARIANTS

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
JELLY = Params.quick()  # the energy case's oscillating jelly: 32 cells, released from a 10 % isochoric stretch


def variant(key):
    return next(v for v in VARIANTS if v.key == key)


def booked(sim, steps, dt=None):
    """Run ``steps`` steps of ``sim`` through a fresh ledger; returns the per-step entries."""
    ledger, entries = EnergyLedger(sim.scene), []
    dt = sim.stepper.time_step(sim.particles) if dt is None else dt
    particles, rigid = sim.particles, sim.state.rigid
    for k in range(steps):
        out = substep(sim.backend, particles, dt, k * dt, rigid=rigid, ledger=ledger)
        particles, rigid = out if rigid is not None else (out, None)
        entries.append(ledger.last)
    sim.particles = particles
    sim.state.rigid = rigid
    return entries


def total_energy(sim):
    """The run's total energy as :meth:`Simulation.diagnostics` reports it."""
    return sim.diagnostics()["total_energy"]


def column(entries, name):
    return np.array([e[name] for e in entries])


# ------------------------------------------------------------------------------------------ signs
@pytest.mark.parametrize("key", ["pic", "mls", "polypic"])
def test_p2g_never_raises_kinetic_energy(key):
    """P2G is a mass-weighted average of the particles' velocity fields: by Cauchy-Schwarz the grid's kinetic
    energy is at most the particles' (Jiang et al. 2015 §6), so ``p2g_transfer`` <= round-off every step."""
    sim = make_simulation(JELLY, "jelly", variant(key))
    e0 = total_energy(sim)
    entries = booked(sim, 25)
    assert column(entries, "p2g_transfer").max() <= 1e-12 * e0
    assert column(entries, "p2g_transfer").min() < -1e-6 * e0  # and it does lose something


def test_pic_g2p_loses_and_full_polypic_g2p_keeps():
    """PIC's G2P interpolates the grid field, losing what is not linear on the stencil: <= 0 every step.
    PolyPIC with all S^d modes represents any stencil velocity exactly (Fu et al. 2017 §5): G2P loses nothing,
    to round-off; what its modes' energy does as the particles move is ``advection``."""
    pic = make_simulation(JELLY, "jelly", variant("pic"))
    e0 = total_energy(pic)
    pic_g2p = column(booked(pic, 25), "g2p_transfer")
    assert pic_g2p.max() <= 1e-12 * e0 and pic_g2p.min() < -1e-4 * e0
    poly = make_simulation(JELLY, "jelly", variant("polypic"))
    entries = booked(poly, 25)
    assert np.abs(column(entries, "g2p_transfer")).max() <= 1e-12 * e0
    assert np.abs(column(entries, "advection")).max() > 1e-7 * e0  # the term that takes the modes' change


def falling_block(wall, friction=0.0, spin=20.0, cells=32):
    """A spinning elastic block dropped onto a floor of type ``wall`` (sticky, slip or separate)."""
    scene = (SceneBuilder(dim=2, name="drop").grid(size=1.0, cells=cells).method("apic")
             .material("m", "fixed_corotated", E=1e3, nu=0.3, rho=1.0)
             .box("m", lower=[0.4, 0.15], upper=[0.6, 0.35], ppc=4)
             .walls(wall, friction=friction).gravity([0.0, -10.0]).time(dt=2e-4, steps=1).build())
    sim = Simulation(scene)
    r = sim.x - sim.x.mean(axis=0)
    sim.v = np.stack([-spin * r[:, 1], spin * r[:, 0] - 2.0], axis=1)
    return sim


@pytest.mark.parametrize("wall,friction", [("sticky", 0.0), ("slip", 0.0), ("separate", 0.0), ("separate", 0.5)])
def test_static_walls_never_add_energy(wall, friction):
    """A static wall's impulse R_i does no positive work on the velocity it leaves (R_i . v_i <= 0 for every
    projection of talk Eq. 25), so ``boundary`` <= round-off every step; the block does hit the floor."""
    sim = falling_block(wall, friction)
    e0 = total_energy(sim)
    b = column(booked(sim, 120), "boundary")
    assert b.max() <= 1e-12 * e0
    assert b.min() < -1e-4 * e0


def test_a_moving_collider_can_add_energy():
    """The sign of ``boundary`` is not forced by its definition: a plane moving at 1 m/s into a block at rest
    pushes it, and ``boundary`` books the energy it adds."""
    scene = (SceneBuilder(dim=2, name="push").grid(size=1.0, cells=32).method("apic")
             .material("m", "fixed_corotated", E=1e3, nu=0.3, rho=1.0)
             .box("m", lower=[0.4, 0.4], upper=[0.6, 0.6], ppc=4)
             .collider("plane", type="sticky", point=[0.395, 0.0], normal=[1.0, 0.0], velocity=[1.0, 0.0])
             .walls("open").time(dt=2e-4, steps=1).build())
    b = column(booked(Simulation(scene), 60), "boundary")
    assert b.sum() > 1e-4


def test_friction_takes_mu_m_g_d():
    """A block sliding at 1 m/s on a floor with Coulomb friction mu decelerates at mu g; the energy the floor takes
    is mu m g d over the distance d slid (the work of the friction force). Measured over 0.1 s (the block slows from
    1 to 0.7 m/s; the energy_ledger case's friction block, run longer): within 5 %."""
    f = ledger_runs.run_friction(replace(ledger_runs.Params.quick(), friction_steps=500), "numpy")
    d = f["distance"][-1]
    assert 0.05 < d < 0.1
    assert -f["boundary"][-1] == pytest.approx(f["mu"] * f["mass"] * f["g"] * d, rel=0.05)


def example_scene(name, **output):
    data = tomllib.loads((EXAMPLES / f"{name}.toml").read_text())
    data.setdefault("output", {}).update(output)
    return Scene.from_dict(data, base_dir=EXAMPLES)


def test_the_return_map_of_sand_never_raises_elastic_energy():
    """Drucker-Prager's return map (Klar et al. 2016 §7.3) projects the Hencky strain onto the yield surface
    along the energy's gradient: the stored energy after it is never above the trial one, so ``plastic`` <=
    round-off; the sand example does yield as it lands."""
    sim = Simulation(example_scene("sand"))
    e0 = total_energy(sim)
    p = column(booked(sim, 60), "plastic")
    assert p.max() <= 1e-12 * e0 and p.min() < -1e-5 * e0


# ------------------------------------------------------------------------------------------ sizes
def test_integration_error_converges_at_first_order():
    """Symplectic Euler's energy error per step is O(dt^2) (Hairer, Lubich & Wanner 2006 ch. IX), so the sum
    of its size over the steps to a fixed time is O(dt): fitted slope in [0.8, 1.3] as dt halves (MLS-MPM on
    the oscillating jelly to t = 0.02 s, as the energy_ledger case measures it). The signed total is not used: its
    two leading parts (the elastic energy's convexity remainder, >= 0, and the kinetic -m|dt a|^2/2, <= 0) cancel to
    leading order."""
    study = ledger_runs.run_integration(replace(ledger_runs.Params.quick(), integration_t_end=0.02), "numpy")
    slope = np.polyfit(np.log(study["dt"]), np.log(study["size"]), 1)[0]
    assert 0.8 <= slope <= 1.3, study


def test_transfer_terms_tend_to_the_pure_transfer_cycle():
    """From one state, a step of dt -> 0 is a pure P2G -> G2P cycle (the transfer_energy case's): p2g_transfer
    does not depend on dt at all, and g2p_transfer tends to its dt = 0 value at first order. At dt = 0 their
    sum is the particles' kinetic energy change, measured independently by the diagnostics."""
    sim = make_simulation(JELLY, "jelly", variant("pic"))
    booked(sim, 10)  # a state in motion
    start = sim.particles
    steps = {}
    for dt in (0.0, 1e-4, 5e-5, 2.5e-5):
        sim.particles = start
        steps[dt] = booked(sim, 1, dt=dt)[0]
    assert {steps[dt]["p2g_transfer"] for dt in steps} == {steps[0.0]["p2g_transfer"]}
    gaps = [abs(steps[dt]["g2p_transfer"] - steps[0.0]["g2p_transfer"]) for dt in (1e-4, 5e-5, 2.5e-5)]
    assert np.log2(gaps[0] / gaps[1]) == pytest.approx(1.0, abs=0.2)
    assert np.log2(gaps[1] / gaps[2]) == pytest.approx(1.0, abs=0.2)
    sim.particles = start
    k0 = sim.diagnostics()["kinetic"]  # PIC carries no affine or mode energy
    booked(sim, 1, dt=0.0)
    k1 = sim.diagnostics()["kinetic"]
    assert steps[0.0]["p2g_transfer"] + steps[0.0]["g2p_transfer"] == pytest.approx(k1 - k0, rel=1e-10)


# ------------------------------------------------------------------------------------------ a planted leak
def test_a_g2p_that_drops_the_affine_term_shows_in_g2p_transfer(monkeypatch):
    """Planted leak: APIC's G2P with C_p set to zero throws away the particles' affine kinetic energy. The
    ledger books the loss where it happens: g2p_transfer falls by the affine energy dropped, while the
    terms of the other stages stay as they were (same step from the same state)."""
    sim = make_simulation(JELLY, "jelly", variant("mls"))
    booked(sim, 10)
    start = sim.particles
    honest = booked(sim, 1)[0]
    backend = sim.backend
    original = type(backend).g2p

    def leaky(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        return out.with_(C=np.zeros_like(out.C))

    sim.particles = start
    with_c = booked(sim, 1)  # the honest step again, to take its affine energy
    affine = 0.5 * sim.scene.kernel.inertia_factor * sim.scene.grid.dx**2 * float(
        np.sum(sim.mass * np.sum(sim.C**2, axis=(1, 2))))
    monkeypatch.setattr(type(backend), "g2p", leaky)
    sim.particles = start
    leaked = booked(sim, 1)[0]
    assert with_c[0]["g2p_transfer"] == honest["g2p_transfer"]
    assert honest["g2p_transfer"] - leaked["g2p_transfer"] == pytest.approx(affine, rel=1e-9)
    for name in ("p2g_transfer", "boundary", "plastic"):
        assert leaked[name] == honest[name]
    assert abs(leaked["integration"] - honest["integration"]) < 0.01 * affine


# ------------------------------------------------------------------------------------------ rigid bodies
def test_rigid_bodies_term_is_the_wheels_damped_energy():
    """CPIC (sand_wheel2d): the wheel (ring and welded blades, pinned) spun at omega = 5 rad/s before the sand
    reaches it. Its angular damping c decays omega by e^{-c dt} a step, so ``rigid_bodies`` must be
    0.5 I omega^2 (e^{-2 c dt} - 1) per step, I the ring's plus the blades' inertia (closed form)."""
    sim = Simulation(example_scene("sand_wheel2d"))
    wheel = [b for b in sim.scene.rigid_bodies if b.motion == "dynamic"]
    omega0, c = 5.0, wheel[0].angular_damping
    sim.state.rigid = sim.state.rigid.with_(angular_velocity=np.where(
        [b.motion == "dynamic" for b in sim.scene.rigid_bodies], omega0, 0.0))
    dt = sim.stepper.time_step(sim.particles)
    entries = booked(sim, 3, dt=dt)
    inertia = sum(b.inertia for b in wheel)
    expected = [0.5 * inertia * (omega0 * np.exp(-c * dt * k))**2 * (np.exp(-2 * c * dt) - 1) for k in range(3)]
    assert column(entries, "rigid_bodies") == pytest.approx(expected, rel=1e-9)
    assert np.abs(column(entries, "closure")).max() < 1e-12 * total_energy(sim)


# ------------------------------------------------------------------------------------------ where users see it
def test_diagnostics_csv_has_the_cumulative_ledger(tmp_path):
    """``[output] energy_ledger = true`` adds ``ledger_<term>`` columns; they add up to the change of
    ``total_energy`` (the telescoping identity, computed: an implementation check, not physics)."""
    scene = example_scene("sand", energy_ledger=True, every=5)
    sim = Simulation(scene, out_dir=tmp_path)
    sim.run(steps=20)
    import csv
    rows = list(csv.DictReader(open(tmp_path / "diagnostics.csv")))
    last, first = rows[-1], rows[0]
    assert all(f"ledger_{c}" in last for c in COLUMNS)
    terms = sum(float(last[f"ledger_{t}"]) for t in TERMS)
    change = float(last["total_energy"]) - float(first["total_energy"])
    assert terms == pytest.approx(change, rel=1e-9)
    assert float(last["ledger_plastic"]) < 0.0


def test_an_asynchronous_scene_takes_the_ledger_and_a_value_not_true_or_false_is_refused():
    """Asynchronous runs book their level updates (tests/test_async_ledger.py); the flag itself must be a boolean."""
    data = tomllib.loads((EXAMPLES / "stork2d.toml").read_text())
    data.setdefault("output", {})["energy_ledger"] = True
    scene = Scene.from_dict(data, base_dir=EXAMPLES)
    assert scene.time.stepping == "async" and scene.output.energy_ledger
    data["output"]["energy_ledger"] = "yes"
    with pytest.raises(SceneError, match="output.energy_ledger"):
        Scene.from_dict(data, base_dir=EXAMPLES)


# ------------------------------------------------------------------------------------------ backends
@pytest.mark.parametrize("case", ["jelly-mls", "jelly-polypic", "sand"])
def test_numba_books_what_the_reference_books(case):
    """The same step from the same state on both backends: every term within 1e-12 relative (of the term, or
    of the run's energy for a term near zero). The ledger reads the stages' outputs, so this is the stages'
    conformance seen through the energy."""
    def simulation(backend):
        if case == "sand":
            return Simulation(example_scene("sand"), backend=backend)
        return make_simulation(JELLY, "jelly", variant(case.split("-")[1]), backend=backend)

    reference, numba = simulation("numpy"), simulation("numba")
    booked(reference, 5)
    numba.particles = reference.particles.copy()
    scale = abs(total_energy(reference))
    dt = reference.stepper.time_step(reference.particles)
    for mine, theirs in zip(booked(numba, 2, dt=dt), booked(reference, 2, dt=dt)):
        for name in COLUMNS:
            assert mine[name] == pytest.approx(theirs[name], rel=1e-12, abs=1e-12 * scale), name


def test_a_resumed_run_goes_on_adding_to_the_ledger(tmp_path):
    """The cumulative ledger is part of the run's state: a run resumed from its checkpoint at step 10 ends
    with the same ledger, bit for bit, as one that ran 20 steps straight."""
    scene = example_scene("sand", energy_ledger=True, every=10)
    straight = Simulation(scene)
    straight.run(steps=20)
    first = Simulation(scene, out_dir=tmp_path)
    first.run(steps=10)
    resumed = Simulation.resume(scene, tmp_path)
    resumed.run(steps=10)
    expected = {k: v for k, v in straight.diagnostics().items() if k.startswith("ledger_")}
    assert {k: v for k, v in resumed.diagnostics().items() if k.startswith("ledger_")} == expected
    assert expected["ledger_plastic"] < 0.0


def test_snow_compressed_past_its_limit_dissipates_the_closed_form():
    """Snow (Stomakhin et al. 2013 §5) held at rest in F = diag(s, s), s = 0.95 < 1 - theta_c: a step of dt = 0
    changes nothing but the return map, which clamps both singular values to 1 - theta_c and moves the rest
    into J_P = s^2 / (1 - theta_c)^2. ``plastic`` must be V0 [Psi(after) - Psi(trial)] with
    Psi = e^{xi (1 - J_P)} [mu sum (sigma - 1)^2 + lambda/2 (J - 1)^2], evaluated here by hand."""
    E, nu, xi, theta_c, s = 1e4, 0.2, 10.0, 0.025, 0.95
    scene = (SceneBuilder(dim=2, name="snow").grid(size=1.0, cells=16).method("mls")
             .material("m", "snow", E=E, nu=nu, rho=1.0, theta_c=theta_c, hardening=xi)
             .box("m", lower=[0.4, 0.4], upper=[0.6, 0.6], ppc=4).walls("open").time(dt=1e-4, steps=1).build())
    sim = Simulation(scene)
    sim.F = np.broadcast_to(np.diag([s, s]), sim.F.shape)
    entry = booked(sim, 1, dt=0.0)[0]
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    clamped = 1.0 - theta_c
    trial = 2 * mu * (s - 1) ** 2 + 0.5 * lam * (s * s - 1) ** 2
    after = np.exp(xi * (1 - s * s / clamped**2)) * (2 * mu * (clamped - 1) ** 2 + 0.5 * lam * (clamped**2 - 1) ** 2)
    assert entry["plastic"] == pytest.approx(float(sim.vol0.sum()) * (after - trial), rel=1e-12)
    assert entry["plastic"] < 0.0


# ------------------------------------------------------------------------------------------ per particle
@pytest.mark.parametrize("case", ["sand", "jelly-polypic"])
def test_the_per_particle_shares_add_up_to_their_terms(case):
    """``plastic`` and ``advection`` are sums over the particles: the shares the ledger keeps add up to the step's
    terms to round-off of the energy scale, belong to the particles the step returned (by id), and are not all zero
    where the term is not (sand yields as it lands; PolyPIC's modes move with the particles)."""
    sim = Simulation(example_scene("sand")) if case == "sand" else make_simulation(JELLY, "jelly", variant("polypic"))
    ledger = EnergyLedger(sim.scene)
    term = "plastic" if case == "sand" else "advection"
    for k in range(40):
        out = substep(sim.backend, sim.particles, 1e-4 if case == "jelly-polypic" else 3e-4, k * 1e-4, ledger=ledger)
        sim.particles = out
        shares = ledger.shares
        assert np.array_equal(shares["id"], out.id)
        assert float(np.sum(shares[term])) == pytest.approx(ledger.last[term], abs=1e-12 * ledger.scale)
    assert np.abs(shares[term]).max() > 0.0 and ledger.last[term] != 0.0
