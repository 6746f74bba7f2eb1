r"""Exercise 5: predict the MLS velocity gradient's error on the quadratic kernel, then measure it.

Task. With the MLS force, the velocity gradient is :math:`\nabla v_p = C_p = B_p D_p^{-1}`
(``docs/mls_vs_classic.md``, equation ``eq-mls-force``). Take the grid field :math:`v = (\sin kx, 0)`
and particles at known offsets :math:`t \in [-\tfrac12, \tfrac12)` from their middle node (in cells).
Predict the error of :math:`\partial v_x/\partial x` as a function of :math:`t` and :math:`\Delta x`, and
its average over a cell; then measure it.

Prediction. Expanding :math:`v(x_i)` to second order around :math:`x_p`, the curvature term leaves
:math:`\tfrac12 v''\,\Delta x\,M_3/M_2` with the kernel moments
:math:`M_k = \sum_i w_{ip}((x_i - x_p)/\Delta x)^k`. For the quadratic B-spline :math:`M_2 = \tfrac14`
and :math:`M_3 = t(\tfrac14 - t^2)` (the nodes sit at :math:`-1-t, -t, 1-t` cells), so

.. math::

    C_{xx} - v'(x_p) \approx 2\,v''(x_p)\, t\,(\tfrac14 - t^2)\,\Delta x,

first order in :math:`\Delta x`, odd in :math:`t`, so its average over offsets spread evenly across a
cell vanishes to this order. The next Taylor term, :math:`\tfrac16 v'''\,\Delta x^2 M_4/M_2`, is second
order and bounds what remains (:math:`M_4 \le M_2` for this kernel). The cubic B-spline has
:math:`M_3 = 0`: its error is second order.

Worked solution. Evaluate the kernel stencil with ``mpmref.physics.kernels.compute_stencil``, sum
:math:`w_{ip} v_i (x_i - x_p)^T / D` over the stencil, and compare with the prediction.
"""

import numpy as np

from mpmref.physics.kernels import KERNELS, compute_stencil

K = 5.0  # wavenumber of the field


def field(x):
    return np.stack([np.sin(K * x[:, 0]), np.zeros(len(x))], axis=1)


def affine_gradient(kernel, x, dx):
    """:math:`C_p = \\sum_i w_{ip} v_i (x_i - x_p)^T D_p^{-1}` of the field sampled at the nodes."""
    st = compute_stencil(KERNELS[kernel], x, np.zeros(2), dx)
    C = np.zeros((len(x), 2, 2))
    for offset in st.offsets:
        w, d = st.node_weight(offset), st.node_offset_vector(offset)
        C += np.einsum("na,nb->nab", w[:, None] * field(x + d), d)
    return C / st.inertia


def particles_at_offsets(t, dx, near=np.pi / (4 * K)):
    """Particles at offset ``t`` (cells) from the node nearest to x = ``near`` (where kx = pi/4: the field's
    slope and curvature are both sizeable), mid-cell in y."""
    node = round(near / dx)
    return np.stack([(node + t) * dx, np.full(len(t), 10.5 * dx)], axis=1)


def solve():
    t = np.linspace(-0.5, 0.5, 40, endpoint=False) + 0.0125   # evenly spread over one cell
    out = {}
    for dx in (1 / 64, 1 / 128):
        x = particles_at_offsets(t, dx)
        measured = affine_gradient("quadratic", x, dx)[:, 0, 0] - K * np.cos(K * x[:, 0])
        predicted = 2.0 * (-K**2 * np.sin(K * x[:, 0])) * t * (0.25 - t**2) * dx
        # the next Taylor term, v''' d^3 / 6, adds at most |v'''| M4/M2 dx^2 / 6 <= K^3 dx^2 / 6
        second_order = K**3 * dx**2 / 6.0
        assert np.abs(measured - predicted).max() < 0.05 * np.abs(predicted).max() + second_order, dx
        assert abs(measured.mean()) < second_order          # the first-order part averages out over a cell
        cubic = affine_gradient("cubic", x, dx)[:, 0, 0] - K * np.cos(K * x[:, 0])
        out[dx] = (np.abs(measured).max(), np.abs(cubic).max())
    (q64, c64), (q128, c128) = out[1 / 64], out[1 / 128]
    assert abs(np.log2(q64 / q128) - 1.0) < 0.1 and abs(np.log2(c64 / c128) - 2.0) < 0.1
    return {"quadratic_max_error": (q64, q128), "cubic_max_error": (c64, c128)}


if __name__ == "__main__":
    print(solve())
