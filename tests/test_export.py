"""``mpmref export``: the start of a scene in plain formats, and the frames another code writes read back
(mpmref/exchange/; docs/comparing_runs.md)."""

import json

import meshio
import numpy as np
import pytest

from mpmref import Scene, Simulation
from mpmref.cli import main
from mpmref.exchange import FrameError, export_start, read_frames
from mpmref.exchange.start import column_names

SCENE = """
name = "pair"
dim = 2
gravity = [0.0, -9.8]
[grid]
size = [1.0, 1.0]
cells = 16
[method]
scheme = "mls"
[materials.jelly]
type = "fixed_corotated"
E = 1000.0
nu = 0.3
rho = 2.0
[materials.water]
type = "fluid"
K = 50.0
gamma = 7.0
rho = 1.0
[[bodies]]
shape = "box"
material = "jelly"
lower = [0.3, 0.5]
upper = [0.5, 0.7]
ppc = 4
[[bodies]]
shape = "box"
material = "water"
lower = [0.55, 0.2]
upper = [0.8, 0.4]
sampling = "random"
count = 40
seed = 3
[boundary]
type = "separate"
friction = 0.25
width = 2
walls = { y_max = { type = "sticky" } }
[time]
dt = 1e-3
steps = 20
[output]
every = 10
"""


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "pair.toml"
    path.write_text(SCENE)
    return path


def start_particles(scene):
    return Simulation(scene).particles


def test_npz_csv_and_vtk_hold_the_start_bit_for_bit(scene_file, tmp_path):
    scene = Scene.from_toml(scene_file)
    export_start(scene, tmp_path / "start")
    p = start_particles(scene)
    with np.load(tmp_path / "start" / "particles.npz") as npz:
        for name in ("x", "v", "mass", "vol0", "material", "C", "F", "J", "id"):
            assert np.array_equal(npz[name], getattr(p, name)) and npz[name].dtype == getattr(p, name).dtype, name
        assert "Jp" not in npz.files  # no plastic material: no Jp
    text = (tmp_path / "start" / "particles.csv").read_text().splitlines()
    header = text[0].split(",")
    assert header[:4] == ["id", "x", "y", "vx"] and "F_xy" in header and "C_yx" in header
    columns = dict(zip(header, np.array([row.split(",") for row in text[1:]], dtype=np.float64).T))
    assert np.array_equal(np.stack([columns["x"], columns["y"]], axis=1), p.x)
    assert np.array_equal(columns["F_xy"], p.F[:, 0, 1]) and np.array_equal(columns["J"], p.J)
    mesh = meshio.read(tmp_path / "start" / "particles.vtu")
    assert np.array_equal(mesh.points[:, :2], p.x) and not mesh.points[:, 2].any()
    assert np.array_equal(np.ravel(mesh.point_data["id"]), p.id)


def test_float32_start_reads_back_to_the_same_float32_bits(scene_file, tmp_path):
    scene = Scene.from_dict({**Scene.from_toml(scene_file).source, "dtype": "float32"})
    export_start(scene, tmp_path)
    p = start_particles(scene)
    lines = (tmp_path / "particles.csv").read_text().splitlines()
    header = lines[0].split(",")
    x = np.array([[row.split(",")[header.index(a)] for a in "xy"] for row in lines[1:]], dtype=np.float32)
    assert p.x.dtype == np.float32 and np.array_equal(x, p.x)
    assert json.loads((tmp_path / "scene.json").read_text())["dtype"] == "float32"


def test_scene_json_holds_every_number_in_plain_units(scene_file, tmp_path):
    scene = Scene.from_toml(scene_file)
    record = json.loads(export_start(scene, tmp_path).read_text())
    assert record["grid"]["dx"] == 1.0 / 16 and record["grid"]["node_shape"] == [17, 17]
    assert record["grid"]["n_nodes"] == 289 and record["kernel"]["inertia"] == 0.25 / 256
    jelly, water = record["materials"]
    E, nu = 1000.0, 0.3
    assert jelly["mu"] == pytest.approx(E / (2 * (1 + nu)), rel=1e-15)
    assert jelly["lam"] == pytest.approx(E * nu / ((1 + nu) * (1 - 2 * nu)), rel=1e-15)
    assert (jelly["index"], jelly["rho"], jelly["evolves"]) == (0, 2.0, ["F"])
    assert (water["K"], water["gamma"], water["evolves"]) == (50.0, 7.0, ["J"])
    assert record["gravity"] == [0.0, -9.8] and record["time"]["dt"] == 1e-3 and record["time"]["steps"] == 20
    walls = record["boundary"]["walls"]
    assert record["boundary"]["order"] == ["x_min", "x_max", "y_min", "y_max"]
    assert walls["y_max"]["type"] == "sticky" and walls["y_min"] == {
        "type": "separate", "friction": 0.25, "axis": 1, "normal": [0.0, 1.0], "nodes": [0, 1]}
    assert walls["x_max"]["nodes"] == [15, 16]  # the reference's band: i > cells - width
    n = start_particles(scene).n
    assert record["particles"]["count"] == n and record["particles"]["fields"]["F"]["shape"] == [n, 2, 2]


def test_column_names():
    assert column_names("x", np.zeros((2, 3))) == ["x", "y", "z"]
    assert column_names("v", np.zeros((2, 2))) == ["vx", "vy"]
    assert column_names("F", np.zeros((2, 2, 2))) == ["F_xx", "F_xy", "F_yx", "F_yy"]


def test_command_line_writes_the_start_and_refuses_a_bad_scene(scene_file, tmp_path, capsys):
    assert main(["export", str(scene_file), str(tmp_path / "out"), "--dtype", "float32"]) == 0
    assert "scene.json" in capsys.readouterr().out
    assert json.loads((tmp_path / "out" / "scene.json").read_text())["dtype"] == "float32"
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENE.replace("nu = 0.3", "nu = 0.7"))
    assert main(["export", str(bad), str(tmp_path / "bad")]) == 2
    assert "materials.jelly.nu" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------- frames
@pytest.fixture
def run_dir(scene_file, tmp_path):
    """The frames of mpmref's own run of the scene (a .pvd series of .vtu with ids), and the run's positions."""
    scene = Scene.from_toml(scene_file)
    sim = Simulation(scene, out_dir=tmp_path / "run")
    sim.run()
    return tmp_path / "run", scene, sim


def test_mpmref_run_frames_read_back_in_id_order(run_dir):
    folder, scene, sim = run_dir
    frames = read_frames(folder / "particles.pvd", 2, np.arange(sim.n_particles))
    assert [f.step for f in frames] == [None] * 3 and [round(f.time / 1e-3) for f in frames] == [0, 10, 20]
    assert np.array_equal(frames[-1].x, sim.x[np.argsort(sim.id)])
    assert set(frames[-1].fields) == {"v", "J"} and frames[-1].fields["v"].shape == (sim.n_particles, 2)
    assert [f.label for f in read_frames(folder, 2, np.arange(sim.n_particles))] == [f.label for f in frames]


def _npz_frames(folder, x, **extra):
    """Two frames whose file names say 0 and 5, whose own ``step`` entries say 0 and 7."""
    folder.mkdir()
    for name, step in ((0, 0), (5, 7)):
        np.savez(folder / f"f_{name}.npz", x=x, step=np.array(step), **extra)


def test_rows_follow_the_ids_and_npz_csv_frames_read(tmp_path):
    rng = np.random.default_rng(1)
    x = rng.random((6, 2))
    shuffle = rng.permutation(6)
    _npz_frames(tmp_path / "npz", x[shuffle], id=shuffle, J=np.arange(6.0)[shuffle])
    frames = read_frames(tmp_path / "npz", 2, np.arange(6))
    assert np.array_equal(frames[0].x, x) and np.array_equal(frames[0].fields["J"], np.arange(6.0))
    assert [f.step for f in frames] == [0, 7] and frames[0].dtype == np.float64
    csv_dir = tmp_path / "csv"
    csv_dir.mkdir()
    body = "\n".join(f"{i},{a!r},{b!r},0.5,-1" for i, (a, b) in zip(shuffle, x[shuffle].tolist()))
    (csv_dir / "out_3.csv").write_text("id,x,y,vx,vy\n" + body + "\n")
    (frame,) = read_frames(csv_dir, 2, np.arange(6))
    assert frame.step == 3 and np.array_equal(frame.x, x) and np.all(frame.fields["v"] == [0.5, -1.0])
    assert frame.dtype is None


@pytest.mark.parametrize("problem, expected", [
    ("count", "has 5 particles, the start has 6"),
    ("nan", "x is not finite for 1 particles (first: row 2)"),
    ("missing id", "1 ids of the start missing (first: [5])"),
    ("z", "nonzero component beyond axis 1"),
    ("unreadable", "cannot be read"),
    ("mixed ids", "has no id array while other frames"),
    ("same step", "is the same step 4"),
])
def test_frames_that_cannot_be_compared_are_refused_naming_file_and_reason(tmp_path, problem, expected):
    x = np.random.default_rng(2).random((6, 2))
    folder = tmp_path / "frames"
    folder.mkdir()
    first, second = folder / "f_0.npz", folder / "f_4.npz"
    np.savez(first, x=x, id=np.arange(6))
    arrays = {"x": x, "id": np.arange(6)}
    if problem == "count":
        arrays = {"x": x[:5], "id": np.arange(5)}
    elif problem == "nan":
        arrays["x"] = np.where(np.arange(6)[:, None] == 2, np.nan, x)
    elif problem == "missing id":
        arrays["id"] = np.array([0, 1, 2, 3, 4, 4])
    elif problem == "z":
        arrays["x"] = np.hstack([x, np.full((6, 1), 0.1)])
    elif problem == "mixed ids":
        del arrays["id"]
    elif problem == "same step":
        np.savez(first, x=x, id=np.arange(6), step=np.array(4))
    if problem == "unreadable":
        second.write_bytes(b"not a zip file")
    else:
        np.savez(second, **arrays)
    with pytest.raises(FrameError) as caught:
        read_frames(folder, 2, np.arange(6))
    assert expected in str(caught.value) and caught.value.path.endswith(".npz")


def test_a_folder_without_frames_and_a_missing_series_file_are_refused(tmp_path):
    with pytest.raises(FrameError, match="holds no frame file"):
        read_frames(tmp_path, 2, np.arange(3))
    (tmp_path / "s.pvd").write_text('<VTKFile><Collection><DataSet timestep="0" file="gone.vtu"/></Collection>'
                                    "</VTKFile>")
    with pytest.raises(FrameError, match="gone.vtu: does not exist"):
        read_frames(tmp_path / "s.pvd", 2, np.arange(3))
