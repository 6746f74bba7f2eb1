"""Other MPM codes that ``mpmref bench --vs NAME`` runs on the same scene, for speed and agreement.

Each peer is our own implementation of mpmref's equations in another framework (never a copy of that
framework's examples), so that the comparison measures the framework, not a different algorithm.

* :mod:`mpmref.peers.taichi_mpm88`: Taichi's CPU backend on the weakly compressible fluid scenes
  (``mpm88`` and its 3D counterpart), MLS-MPM with J-tracking, as in the NumPy reference.
"""

PEERS = ("taichi",)
