"""Named groups of the compiled kernels' arguments.

A transfer kernel reads the grid's layout, the order in which particles are visited and, with CPIC, the
bodies and the particle–node contact: a few dozen arrays and numbers. Numba passes a
:func:`collections.namedtuple` of them as one argument (its type is part of the compiled signature, like an
array's), and a kernel unpacks it in its first lines, so the arithmetic that follows reads the same names as
before and compiles to the same code. The groups are built once per stage call by the backend
(:mod:`.backend`, :mod:`.cpic.stages`).
"""

from collections import namedtuple

#: A sparse grid's layout (:class:`~.sparse.BlockLayout`): grid origin, cell size, the APIC inertia
#: :math:`D_p`, the block-pointer table ``slot_of`` and its strides.
SparseLayout = namedtuple("SparseLayout", "origin dx inertia slot_of table_strides")

#: A dense grid's layout (the CPIC stages): grid origin, cell size, :math:`D_p` and the node strides.
DenseLayout = namedtuple("DenseLayout", "origin dx inertia strides")

#: The order in which a kernel visits the particles (:mod:`.blocks`): ``order[start[g]:start[g + 1]]`` are
#: the particles of group (slab or block) ``g``; ``groups[colour_start[c]:colour_start[c + 1]]`` the groups
#: of colour ``c``.
Groups = namedtuple("Groups", "order start groups colour_start")

#: The rigid bodies as a CPIC stage sees them: reference points, velocities, angular velocities (scalars in
#: 2D, vectors in 3D) and the encoded friction of each body's two sides.
Bodies = namedtuple("Bodies", "position velocity omega friction")

#: The particle–node contact of a CPIC step: the mask of each particle's incompatible stencil nodes, each
#: node's nearest body and distance, and each particle's ``near`` flag, distance, normal and side tags.
ContactArrays = namedtuple("ContactArrays", "incompatible node_body node_d near phi normal tag_T")
