"""The run: a :class:`~mpmref.run.simulation.Simulation` steps a scene's particles and writes its outputs.

* :mod:`~mpmref.run.simulation`: particle state, stepper, backend, outputs and diagnostics, checkpoints and failures;
* :mod:`~mpmref.run.emitters`: particles added during a run (``[[emitters]]``);
* :mod:`~mpmref.run.domain`: what happens to particles that leave the valid region (``boundary.domain_exit``);
* :mod:`~mpmref.run.stability`: the per-step velocity bound and the CFL warnings;
* :mod:`~mpmref.run.arguments`: the checks of what a caller passes to the run (time steps, end times, step counts).
"""
