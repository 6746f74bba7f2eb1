"""What enters a run (``[[emitters]]``) and what leaves it (deleted at the domain's edge): booked apart from the steps.

* The run's energy ledger has the terms ``inflow`` and ``outflow``: with them its terms add up to the diagnostics'
  E(t) - E0 to round-off, ``inflow`` is the energy of the releases computed by hand and ``outflow`` the energy of the
  particles the run deleted.
* The run's summary computes its drifts against the start plus what entered minus what left: in a scene with nothing
  external (no gravity, no walls) APIC conserves mass and momentum to round-off while particles enter and leave, and
  the energy drift is what the steps' ledger terms say; ``mpmref run`` prints what entered and left on a line of its
  own.
* A resumed run records the same as the uninterrupted one, and a run whose particles stay in a device's memory the
  same as a host run.
"""

import csv
import tomllib

import numpy as np
import pytest
from helpers import full_and_resumed_runs

from mpmref import Scene, Simulation
from mpmref.cli import main
from mpmref.observe.ledger import RUN_TERMS, TERMS, energy_scale
from mpmref.run.emitters import release_template

#: a disk of jelly thrown out through the open floor while an emitter releases more above it, every 0.05 s until 0.35 s
SCENE = """
name = "exchanging"
dim = 2
gravity = [0.0, -10.0]

[grid]
size = [1.0, 1.0]
cells = 32

[method]
scheme = "apic"

[materials.jelly]
type = "fixed_corotated"
E = 10.0
nu = 0.3
rho = 1.0

[[bodies]]
shape = "disk"
material = "jelly"
center = [0.5, 0.3]
radius = 0.05
velocity = [0.0, -3.0]

[[emitters]]
material = "jelly"
center = [0.5, 0.7]
radius = 0.05
velocity = [0.0, -2.0]
until = 0.35

[boundary]
type = "separate"
domain_exit = "delete"

[boundary.walls.y_min]
type = "open"

[time]
dt = 0.0025
t_end = 0.4

[output]
energy_ledger = true
"""
#: the ledger's round-off a step, over the run's energy scale (verification.energy_ledger.reporting.ROUNDOFF)
ROUNDOFF = 1e-12


def scene_data(**changes):
    data = tomllib.loads(SCENE)
    data.update(changes)
    return data


def energies(sim):
    """K + Ψ + U of the particles, and the energy scale of the state (mpmref.observe.ledger.energy_scale)."""
    d = sim.diagnostics()
    kinetic = d["kinetic"] + d["kinetic_affine"] + d["kinetic_modes"]
    return d["total_energy"], energy_scale(kinetic, d["elastic"], d["gravitational"])


def release_energy(scene):
    r"""One release's energy by hand: at rest but for the emitter's velocity, F = I, so
    :math:`\sum_p \tfrac12 m_p |v_e|^2 - m_p\, g \cdot x_p`."""
    emitter = scene.emitters[0]
    template = release_template(scene, emitter)
    m, x = template.mass, template.x
    v = np.asarray(emitter.body.params["velocity"], dtype=float)
    return float(np.sum(0.5 * m * (v @ v)) - np.sum(m * (x @ scene.gravity))), template.n


@pytest.mark.parametrize("scheme", ["apic", "polypic"])
def test_the_ledger_books_what_enters_and_leaves_and_its_terms_add_up_to_the_energy_change(scheme):
    scene = Scene.from_dict(scene_data(method={"scheme": scheme}))
    sim = Simulation(scene)
    e0, scale = energies(sim)
    while sim.time < 0.4 - 1e-12:
        sim.step(t_end=0.4)
        scale = max(scale, energies(sim)[1])
    d = sim.diagnostics()
    assert sim.deleted > 0 and d["entered_particles"] > 0  # particles entered and left
    terms = sum(d[f"ledger_{t}"] for t in RUN_TERMS)
    assert abs(terms - (d["total_energy"] - e0)) <= (sim.step_count + 2) * ROUNDOFF * scale
    steps_alone = sum(d[f"ledger_{t}"] for t in TERMS)  # what the old ledger summed: misses the exchange by far
    assert abs(steps_alone - (d["total_energy"] - e0)) > 0.1 * scale
    per_release, n = release_energy(scene)
    releases = 7  # at t = 0, 0.05, ..., 0.3 (the interval 2 r / |v|), none at or after 0.35
    assert d["entered_particles"] == releases * n
    assert d["ledger_inflow"] == pytest.approx(releases * per_release, rel=1e-12)
    assert d["left_particles"] == sim.deleted
    assert d["ledger_outflow"] == pytest.approx(-d["left_energy"], rel=1e-15) and d["left_energy"] != 0.0


def test_the_drifts_are_of_what_stays_while_particles_enter_and_leave():
    """No gravity, no walls: APIC's transfers conserve mass and momentum, so the run's drifts against the start plus
    what entered minus what left are round-off though the totals change by order one; the energy drift is what the
    steps' terms of the ledger add up to (the releases hit a disk at rest: APIC's transfers dissipate)."""
    data = scene_data(gravity=[0.0, 0.0])
    data["boundary"] = {"type": "open", "domain_exit": "delete"}
    data["bodies"].append({**data["bodies"][0], "center": [0.5, 0.45], "velocity": [0.0, 0.0]})
    sim = Simulation(Scene.from_dict(data))
    first = sim.diagnostics()
    summary = sim.run(t_end=0.4)
    last = summary["final"]
    assert sim.deleted > 0 and abs(last["mass"] - first["mass"]) > 0.5 * first["mass"]
    assert abs(summary["mass_drift_rel"]) <= 1e-14
    assert summary["momentum_drift_rel"] <= 1e-12
    assert np.linalg.norm([last["momentum_y"] - first["momentum_y"]]) > 0.1 * first["mass"]
    steps = sum(last[f"ledger_{t}"] for t in TERMS)
    scale = abs(first["total_energy"]) + abs(summary["entered"]["energy"])
    assert summary["energy_drift_rel"] * scale == pytest.approx(steps, abs=(sim.step_count + 2) * ROUNDOFF * scale)
    assert summary["energy_drift_rel"] < -1e-6  # the collisions take energy: a drift that is not round-off
    assert summary["entered"]["particles"] == last["entered_particles"] and summary["left"]["particles"] == sim.deleted


def test_mpmref_run_prints_what_entered_and_left_on_a_line_of_its_own(tmp_path, capsys):
    path = tmp_path / "exchanging.toml"
    path.write_text(SCENE)
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--steps", "40", "--no-progress"]) == 0
    out = capsys.readouterr().out
    with open(tmp_path / "run" / "diagnostics.csv") as f:
        rows = list(csv.DictReader(f))
    first, last = rows[0], rows[-1]

    def figures(direction):
        return tuple(float(last[f"{direction}_{k}"]) - float(first[f"{direction}_{k}"])
                     for k in ("particles", "mass", "energy"))

    (entered, left) = figures("entered"), figures("left")
    assert entered[0] > 0 and left[0] > 0
    line = next(line for line in out.splitlines() if line.startswith("in and out"))
    assert (f"entered: {entered[0]:.0f} particles, mass {entered[1]:.4g}, energy {entered[2]:.4g}; "
            f"left: {left[0]:.0f} particles, mass {left[1]:.4g}, energy {left[2]:.4g}") in line
    assert "mass drift       " in out and "against the start + entered - left" in out


def test_a_resumed_run_records_what_entered_and_left_as_the_uninterrupted_one(tmp_path):
    data = scene_data()
    data["output"] = {"energy_ledger": True, "every": 40}
    full, resumed = full_and_resumed_runs(Scene.from_dict(data), tmp_path, steps=120, stop_at=60)
    for name in ("entered", "left", "energy_ledger"):
        assert np.array_equal(resumed.state.stepper[name], full.state.stepper[name]), name
    assert full.diagnostics()["left_particles"] > 0


def test_a_run_that_keeps_its_particles_in_a_device_memory_books_what_the_host_run_books():
    """The GPU backend's residency, with the CPU stand-in of tests/test_cuda_residency.py: releases join on the host
    copy and deletions are found by the host checks, and both are booked to the last bit as a host run books them."""
    from test_cuda_residency import RemoteBackend

    scene = Scene.from_dict(scene_data())
    host, remote = Simulation(scene), Simulation(scene, backend=RemoteBackend)
    assert remote.resident
    host.run(steps=60)
    remote.run(steps=60)
    booked = host.diagnostics()
    assert booked["left_particles"] == host.deleted > 0 and booked["entered_particles"] > 0
    assert remote.diagnostics() == booked
