"""The output folder of a run: particle/grid VTK series, ``.pvd`` indexes, ``diagnostics.csv``, checkpoint."""

import csv
import io
from pathlib import Path

import numpy as np

from .atomic import write_text_atomic
from .checkpoint import load_checkpoint, save_checkpoint
from .vtk import write_grid_vti, write_particles_vtu, write_polylines_vtp, write_pvd

CHECKPOINT_NAME = "checkpoint.npz"
#: the files a run writes into its folder (``last_good_*`` only when it fails)
RUN_FILE_PATTERNS = ("particles_*.vtu", "grid_*.vti", "rigid_bodies_*.vtp", "particles.pvd", "grid.pvd",
                     "rigid_bodies.pvd", "diagnostics.csv", CHECKPOINT_NAME, "last_good_*.npz")


def run_files(folder):
    """The files of an earlier run in ``folder`` (sorted; empty if the folder is absent or holds none)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted({p for pattern in RUN_FILE_PATTERNS for p in folder.glob(pattern) if p.is_file()})


def clear_run(folder):
    """Remove the files of an earlier run from ``folder`` (other files are left alone); returns how many."""
    files = run_files(folder)
    for path in files:
        path.unlink()
    return len(files)


class RunOutput:
    """Writes the files of one run into ``out_dir`` and remembers what it wrote (for resuming)."""

    def __init__(self, out_dir, scene):
        self.dir = Path(out_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.scene = scene
        self.particle_series = []  # [(time, file)]
        self.grid_series = []
        self.rigid_series = []
        self.rows = []  # diagnostics rows (dicts)

    @property
    def checkpoint_path(self):
        return self.dir / CHECKPOINT_NAME

    def write_frame(self, step, time, x, point_data, grid_data=None, polylines=None):
        """Write one frame: particles, and the grid and rigid bodies (``polylines``) if given.

        ``grid_data`` is ``(first_node, node_shape, arrays)``: node arrays in C order over the box of nodes
        that starts at the node index ``first_node`` (see :meth:`mpmref.run.simulation.Simulation.grid_data`).
        """
        name = f"particles_{step:06d}.vtu"
        write_particles_vtu(self.dir / name, x, point_data)
        self.particle_series.append((time, name))
        write_pvd(self.dir / "particles.pvd", self.particle_series)
        if grid_data is not None:
            gname = f"grid_{step:06d}.vti"
            g = self.scene.grid
            first_node, node_shape, arrays = grid_data
            write_grid_vti(self.dir / gname, g.origin + g.dx * np.asarray(first_node), g.dx, node_shape, arrays)
            self.grid_series.append((time, gname))
            write_pvd(self.dir / "grid.pvd", self.grid_series)
        if polylines is not None:
            rname = f"rigid_bodies_{step:06d}.vtp"
            write_polylines_vtp(self.dir / rname, polylines)
            self.rigid_series.append((time, rname))
            write_pvd(self.dir / "rigid_bodies.pvd", self.rigid_series)

    def write_diagnostics(self, row):
        self.rows.append(row)
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(self.rows[0]))
        writer.writeheader()
        writer.writerows(self.rows)
        write_text_atomic(self.dir / "diagnostics.csv", buf.getvalue())

    def bookkeeping(self):
        return {"particle_series": self.particle_series, "grid_series": self.grid_series,
                "rigid_series": self.rigid_series, "rows": self.rows}

    def restore(self, book):
        self.particle_series = [tuple(e) for e in book["particle_series"]]
        self.grid_series = [tuple(e) for e in book["grid_series"]]
        self.rigid_series = [tuple(e) for e in book.get("rigid_series", [])]
        self.rows = list(book["rows"])

    def save_checkpoint(self, state, meta, path=None):
        path = path or self.checkpoint_path
        save_checkpoint(path, state, {**meta, "output": self.bookkeeping()})
        return path

    def load_checkpoint(self):
        return load_checkpoint(self.checkpoint_path)
