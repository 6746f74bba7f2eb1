"""The stepper contract (mpmref.steppers.Stepper): both steppers fulfil it, and the asynchronous schedule is a typed
record that round-trips through the state's arrays (what checkpoints store)."""

import inspect

import numpy as np
import pytest
from test_async import EXAMPLES

from mpmref import Scene, Simulation
from mpmref.state import State
from mpmref.steppers import AsynchronousStepper, AsyncSchedule, Stepper, SynchronousStepper


@pytest.mark.parametrize("example", ["stork2d", "jelly"])
def test_both_steppers_fulfil_the_contract(example):
    sim = Simulation(Scene.from_toml(EXAMPLES / f"{example}.toml"))
    assert isinstance(sim.stepper, Stepper)
    for name, member in inspect.getmembers(Stepper, inspect.isfunction):
        if name.startswith("_"):
            continue
        ours = getattr(type(sim.stepper), name)
        assert list(inspect.signature(ours).parameters) == list(inspect.signature(member).parameters), name
    assert isinstance(sim.stepper, AsynchronousStepper if example == "stork2d" else SynchronousStepper)


def test_the_simulation_and_the_command_line_do_not_test_the_steppers_name():
    import mpmref.cli
    import mpmref.run.simulation

    for module in (mpmref.run.simulation, mpmref.cli):
        source = inspect.getsource(module)
        assert "stepper.name" not in source and "hasattr(self.stepper" not in source


def test_the_schedule_round_trips_through_the_state_arrays():
    sim = Simulation(Scene.from_toml(EXAMPLES / "stork2d.toml"))
    sim.step()
    schedule = AsyncSchedule.of(sim.state)
    assert schedule.sync_times == 1 and schedule.own_updates > 0 and schedule.updates >= schedule.own_updates
    again = AsyncSchedule.of(State(particles=sim.particles, stepper=schedule.arrays()))
    assert np.array_equal(again.block_dt, schedule.block_dt)
    assert {k: v for k, v in vars(again).items() if k != "block_dt"} == \
        {k: v for k, v in vars(schedule).items() if k != "block_dt"}
