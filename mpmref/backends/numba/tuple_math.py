"""Small-vector algebra of the transfer kernels on tuples (values a compiled loop keeps in registers): rows and
matrices of arrays as tuples, zeros, ``y + a x``, outer-product updates and the cross product. ``dim`` is a
compile-time constant at every call (2 or 3), so only one branch of each helper is compiled."""

from numba import njit


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
        return (y[0] + a * x[0], y[1] + a * x[1])
    return (y[0] + a * x[0], y[1] + a * x[1], y[2] + a * x[2])


@njit(cache=True, inline="always")
def cross(a, b):
    """The cross product of 3-tuples."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def add_outer(M, u, d, dim):
    """``M + u d^T`` of a d x d matrix ``M`` held as a flat row-major tuple and d-tuples ``u``, ``d``."""
    if dim == 2:
        return (M[0] + u[0] * d[0], M[1] + u[0] * d[1], M[2] + u[1] * d[0], M[3] + u[1] * d[1])
    return (M[0] + u[0] * d[0], M[1] + u[0] * d[1], M[2] + u[0] * d[2],
            M[3] + u[1] * d[0], M[4] + u[1] * d[1], M[5] + u[1] * d[2],
            M[6] + u[2] * d[0], M[7] + u[2] * d[1], M[8] + u[2] * d[2])


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
