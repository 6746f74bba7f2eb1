"""The observers of a run: what it measures, without changing what the stages compute.

* :mod:`.diagnostics`: energies, momenta, mass and their scales, per state;
* :mod:`.ledger`: the energy ledger, each step's energy change booked by stage.
"""
