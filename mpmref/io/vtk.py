"""VTK writers: particles as ``.vtu`` (meshio), grids as ``.vti`` (pyvista), series as ``.pvd``."""

from xml.sax.saxutils import quoteattr

import numpy as np

from .atomic import atomic_path, write_text_atomic


def _pad3(a):
    """Pad 2D vectors (n, 2) to 3D (n, 3) with zeros, as VTK expects 3-component vectors."""
    if a.ndim == 2 and a.shape[1] == 2:
        return np.hstack([a, np.zeros((a.shape[0], 1), dtype=a.dtype)])
    if a.ndim == 3 and a.shape[1:] == (2, 2):
        out = np.zeros((a.shape[0], 3, 3), dtype=a.dtype)
        out[:, :2, :2] = a
        return out.reshape(a.shape[0], 9)
    if a.ndim == 3:
        return a.reshape(a.shape[0], -1)
    return a


def write_particles_vtu(path, x, point_data):
    """Write particles at ``x`` (n, d) as VTK vertex cells with ``point_data`` (name -> array), atomically."""
    import meshio

    points = _pad3(np.asarray(x, dtype=np.float64))
    cells = [("vertex", np.arange(len(points), dtype=np.int64).reshape(-1, 1))]
    data = {k: _pad3(np.asarray(v)) for k, v in point_data.items()}
    with atomic_path(path) as tmp:
        meshio.write(tmp, meshio.Mesh(points, cells, point_data=data), file_format="vtu")


def write_grid_vti(path, origin, dx, node_shape, point_data):
    """Write nodal fields on a regular grid as VTK ImageData (pyvista), atomically.

    ``point_data`` arrays are in C order over ``node_shape`` (first axis slowest), as mpmref stores them.
    """
    import pyvista as pv

    dims = tuple(node_shape) + (1,) * (3 - len(node_shape))
    img = pv.ImageData(dimensions=dims, spacing=(dx,) * 3, origin=tuple(origin) + (0.0,) * (3 - len(origin)))
    for name, values in point_data.items():
        values = np.asarray(values)
        comps = values.reshape(*node_shape, -1)
        # VTK orders points with x fastest: transpose the C-ordered (x, y[, z]) node array
        comps = np.transpose(comps, tuple(reversed(range(len(node_shape)))) + (len(node_shape),))
        flat = _pad3(comps.reshape(-1, comps.shape[-1])) if comps.shape[-1] > 1 else comps.reshape(-1)
        img.point_data[name] = flat
    with atomic_path(path) as tmp:
        img.save(str(tmp))


def write_polylines_vtp(path, polylines):
    """Write 2D polylines or 3D triangle meshes as one VTK PolyData file (ASCII ``.vtp``), atomically.

    ``polylines`` is a list of ``(vertices (n, 2), segments (m, 2))`` (line cells) or ``(vertices (n, 3),
    triangles (m, 3))`` (polygon cells), one per body; the ``body`` cell array holds each cell's body index.
    """
    points, lines, body, offset = [], [], [], 0
    for r, (vertices, segments) in enumerate(polylines):
        points.append(_pad3(np.asarray(vertices, dtype=np.float64)))
        lines.append(np.asarray(segments, dtype=np.int64) + offset)
        body.append(np.full(len(segments), r, dtype=np.int64))
        offset += len(vertices)
    points, lines, body = np.concatenate(points), np.concatenate(lines), np.concatenate(body)
    corners = lines.shape[1]  # 2: line cells, 3: triangles
    section, counts = ("Lines", (len(lines), 0)) if corners == 2 else ("Polys", (0, len(lines)))

    def ascii(a, fmt):
        return " ".join(fmt % v for v in np.ravel(a))

    text = f"""<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">
  <PolyData>
    <Piece NumberOfPoints="{len(points)}" NumberOfVerts="0" NumberOfLines="{counts[0]}" NumberOfStrips="0" \
NumberOfPolys="{counts[1]}">
      <Points>
        <DataArray type="Float64" NumberOfComponents="3" format="ascii">{ascii(points, "%.17g")}</DataArray>
      </Points>
      <{section}>
        <DataArray type="Int64" Name="connectivity" format="ascii">{ascii(lines, "%d")}</DataArray>
        <DataArray type="Int64" Name="offsets" format="ascii">\
{ascii(corners * np.arange(1, len(lines) + 1), "%d")}</DataArray>
      </{section}>
      <CellData Scalars="body">
        <DataArray type="Int64" Name="body" format="ascii">{ascii(body, "%d")}</DataArray>
      </CellData>
    </Piece>
  </PolyData>
</VTKFile>
"""
    write_text_atomic(path, text)


def write_pvd(path, entries):
    """Write a ParaView collection file listing ``entries`` = [(time, relative_file), ...], atomically."""
    lines = ['<?xml version="1.0"?>',
             '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">', "  <Collection>"]
    lines += [f'    <DataSet timestep="{t!r}" group="" part="0" file={quoteattr(f)}/>' for t, f in entries]
    lines += ["  </Collection>", "</VTKFile>", ""]
    write_text_atomic(path, "\n".join(lines))
