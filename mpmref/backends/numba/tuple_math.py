"""Small-vector algebra of the transfer kernels on tuples (values a compiled loop keeps in registers): rows and
matrices of arrays as tuples, zeros, ``y + a x``, outer-product updates and the cross product. ``dim`` is a
compile-time constant at every call (2 or 3), so only one branch of each helper is compiled.

The sums of products over a stencil are fused multiply-adds written out (:func:`fma`: :math:`ab + c` rounded once),
not left to the compiler: a compiler licensed to contract a product and a sum chooses which product of
:math:`ab + cd` to fuse by how it schedules the code, so a kernel compiled in parallel and the same kernel compiled
serially could round differently. Written out, every build rounds alike.
"""

from numba import njit, types
from numba.extending import intrinsic


@intrinsic
def fma(typingctx, a, b, c):
    """:math:`ab + c` rounded once (LLVM's ``llvm.fma``: one instruction where the CPU has it), in the widest
    floating type of the three."""
    if not all(isinstance(t, types.Float) for t in (a, b, c)):
        return None
    real = max((a, b, c), key=lambda t: t.bitwidth)

    def codegen(context, builder, signature, args):
        x, y, z = (context.cast(builder, v, t, real) for v, t in zip(args, signature.args))
        return builder.fma(x, y, z)

    return real(a, b, c), codegen


@njit(cache=True, inline="always")
def zeros(real, dim):
    """A d-tuple of zeros of scalar type ``real``."""
    if dim == 2:
        return (real(0.0), real(0.0))
    return (real(0.0), real(0.0), real(0.0))


@njit(cache=True, inline="always")
def zeros2(real, dim):
    """A d x d matrix of zeros of scalar type ``real`` as a flat tuple (row-major)."""
    if dim == 2:
        return (real(0.0), real(0.0), real(0.0), real(0.0))
    return (real(0.0), real(0.0), real(0.0), real(0.0), real(0.0), real(0.0), real(0.0), real(0.0), real(0.0))


@njit(cache=True, inline="always")
def axpy(y, a, x, dim):
    """``y + a x`` of d-tuples."""
    if dim == 2:
        return (fma(a, x[0], y[0]), fma(a, x[1], y[1]))
    return (fma(a, x[0], y[0]), fma(a, x[1], y[1]), fma(a, x[2], y[2]))


@njit(cache=True, inline="always")
def cross(a, b):
    """The cross product of 3-tuples."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def add_outer(M, u, d, dim):
    """``M + u d^T`` of a d x d matrix ``M`` held as a flat row-major tuple and d-tuples ``u``, ``d``."""
    if dim == 2:
        return (fma(u[0], d[0], M[0]), fma(u[0], d[1], M[1]), fma(u[1], d[0], M[2]), fma(u[1], d[1], M[3]))
    return (fma(u[0], d[0], M[0]), fma(u[0], d[1], M[1]), fma(u[0], d[2], M[2]),
            fma(u[1], d[0], M[3]), fma(u[1], d[1], M[4]), fma(u[1], d[2], M[5]),
            fma(u[2], d[0], M[6]), fma(u[2], d[1], M[7]), fma(u[2], d[2], M[8]))


@njit(cache=True, inline="always")
def row(a, p, dim):
    """``a[p]`` of an (n, d) array as a d-tuple (held in registers by the compiled loop)."""
    if dim == 2:
        return (a[p, 0], a[p, 1])
    return (a[p, 0], a[p, 1], a[p, 2])


@njit(cache=True, inline="always")
def scaled_row(a, p, scale, dim):
    """``scale * a[p]`` of an (n, d) array as a d-tuple."""
    if dim == 2:
        return (scale * a[p, 0], scale * a[p, 1])
    return (scale * a[p, 0], scale * a[p, 1], scale * a[p, 2])


@njit(cache=True, inline="always")
def matrix(a, scale, dim):
    """``scale * a`` of a (d, d) array as a d-tuple of d-tuples."""
    if dim == 2:
        return ((scale * a[0, 0], scale * a[0, 1]), (scale * a[1, 0], scale * a[1, 1]))
    return ((scale * a[0, 0], scale * a[0, 1], scale * a[0, 2]),
            (scale * a[1, 0], scale * a[1, 1], scale * a[1, 2]),
            (scale * a[2, 0], scale * a[2, 1], scale * a[2, 2]))
