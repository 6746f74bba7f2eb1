"""Outputs: VTK series (meshio, pyvista), ParaView ``.pvd`` index, diagnostics CSV, checkpoints."""
