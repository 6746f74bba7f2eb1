r"""The transfer scheme of a scene, resolved once from its declared method.

A scene declares ``method.scheme`` (``pic``, ``flip``, ``apic``, ``polypic`` or ``mls``), ``method.force``
(``mls`` or ``classic``) and ``method.kernel``. :func:`resolve` turns them, with the scene's dimension and
materials, into one :class:`TransferSpec` of plain values that every consumer reads: both backends (the
Numba backend compiles it into its kernels), particle allocation, the conformance harness and the
verification cases.

``"mls"`` is not a transfer of its own: MLS-MPM (Hu et al. 2018 §4) is the APIC transfer (Jiang et al.
2015) with the MLS force, so ``scheme = "mls"`` resolves to ``transfer = "apic"`` with ``force = "mls"``
and gives the same numbers as ``scheme = "apic"`` with the default force.
"""

from typing import NamedTuple

from .kernels import get_kernel

#: declared scheme -> the transfer it uses
TRANSFER_OF = {"pic": "pic", "flip": "flip", "apic": "apic", "polypic": "polypic", "mls": "apic"}


class TransferSpec(NamedTuple):
    r"""What a scene's transfers are; plain values only (the Numba backend's compile-time constants).

    Attributes
    ----------
    scheme : str
        The declared scheme (``"mls"`` kept for reports).
    transfer : str
        ``pic``, ``flip``, ``apic`` or ``polypic``.
    force : str
        ``mls`` (:math:`w_{ip} D_p^{-1}(x_i - x_p)`) or ``classic`` (:math:`\nabla w_{ip}`).
    kernel : str
        ``linear``, ``quadratic`` or ``cubic``.
    support : int
        Kernel support in nodes per axis.
    dim : int
        Dimension, 2 or 3.
    affine : bool
        Particles carry :math:`C_p` through P2G (APIC, PolyPIC, MLS-MPM).
    polypic : bool
        Particles carry PolyPIC's higher modes.
    flip : bool
        G2P blends the FLIP increment.
    flip_alpha : float
        The FLIP fraction (0 unless ``flip``).
    mls_force : bool
        The MLS force (P2G): ``force == "mls"``.
    gradient : str
        The velocity gradient of the ``F``/``J`` update: ``mls`` (:math:`C_p`) or ``classic``
        (:math:`\sum_i v_i \nabla w_{ip}^T`); declared as ``method.velocity_gradient``, which follows
        ``method.force`` unless set.
    mls_gradient : bool
        ``gradient == "mls"`` (G2P).
    tracks_F, tracks_J, tracks_Jp : bool
        Deformation state the materials need.
    """

    scheme: str
    transfer: str
    force: str
    kernel: str
    support: int
    dim: int
    affine: bool
    polypic: bool
    flip: bool
    flip_alpha: float
    mls_force: bool
    gradient: str
    mls_gradient: bool
    tracks_F: bool
    tracks_J: bool
    tracks_Jp: bool


def resolve(method, dim, materials):
    """The :class:`TransferSpec` of a declared ``method`` (a ``MethodSpec``) for ``dim`` and ``materials``."""
    transfer = TRANSFER_OF[method.scheme]
    return TransferSpec(
        scheme=method.scheme, transfer=transfer, force=method.force, kernel=method.kernel,
        support=get_kernel(method.kernel).support, dim=dim,
        affine=transfer in ("apic", "polypic"), polypic=transfer == "polypic", flip=transfer == "flip",
        flip_alpha=float(method.flip_alpha) if transfer == "flip" else 0.0, mls_force=method.force == "mls",
        gradient=method.velocity_gradient, mls_gradient=method.velocity_gradient == "mls",
        tracks_F=any(m.tracks == "F" for m in materials), tracks_J=any(m.tracks == "J" for m in materials),
        tracks_Jp=any(getattr(m, "plastic", False) for m in materials))
