"""The observers of a run: what it measures, without changing what the stages compute.

* :mod:`~mpmref.observe.diagnostics`: energies, momenta, mass and their scales, per state;
* :mod:`~mpmref.observe.ledger`: the energy ledger, each step's energy change booked by stage.
"""
