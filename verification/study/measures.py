r"""Measures to pass to ``mpmref study --measure`` by name, and the pattern for your own.

A measure is a function of the finished :class:`~mpmref.run.simulation.Simulation` that returns named scalars; the
study records them with the run's metrics and measures their orders. Write your own in a module of your own
folder (the command line can import it from there) and pass it as ``--measure my_module:my_measure``.
"""

import numpy as np


def shape(sim):
    r"""Where the material is and how spread out: its centre of mass and radius of gyration,

    .. math:: x_c = \frac{1}{M}\sum_p m_p x_p, \qquad R_g = \Big(\frac{1}{M}\sum_p m_p |x_p - x_c|^2\Big)^{1/2},

    as ``center_x``, ``center_y`` (``center_z``) and ``radius_of_gyration`` (:math:`R/\sqrt2` for a uniform disk of
    radius :math:`R`, :math:`R\sqrt{3/5}` for a ball).
    """
    m, x = sim.mass.astype(np.float64), sim.x.astype(np.float64)
    center = m @ x / m.sum()
    radius = np.sqrt(m @ np.sum((x - center) ** 2, axis=1) / m.sum())
    return {**{f"center_{'xyz'[a]}": float(c) for a, c in enumerate(center)}, "radius_of_gyration": float(radius)}
