"""``mpmref verify --scene`` says what its comparison along the scene's run exercised, and warns about what it did
not: a block in free fall keeps C at round-off, so a code whose C is 25 % wrong agrees with the reference along it
(tests/declared_backends.py ``WrongC``; its angular momentum check catches it, from a spinning start)."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FALL = """name = "fall"
dim = 2
gravity = [0.0, -9.8]
[grid]
size = 1.0
cells = 32
[materials.jelly]
type = "fixed_corotated"
E = 1000.0
rho = 1.0
[[bodies]]
shape = "box"
material = "jelly"
lower = [0.4, 0.5]
upper = [0.6, 0.7]
[boundary]
type = "sticky"
[time]
dt = 1e-4
steps = 300
"""


def test_a_free_fall_is_reported_as_not_exercising_c_f_or_the_walls(tmp_path):
    scene = tmp_path / "fall.toml"
    scene.write_text(FALL)
    run = subprocess.run([sys.executable, "-m", "mpmref.cli", "verify", "--scene", str(scene), "--quick", "--backend",
                          "declared_backends:WrongC", "--out", str(tmp_path / "v"), "--no-progress"],
                         capture_output=True, text=True, timeout=600,
                         env=dict(os.environ, PYTHONPATH=str(ROOT / "tests")))
    data = json.loads((tmp_path / "v" / "results.json").read_text())
    reference = [c for c in data["checks"] if c["case"] == "reference"]
    assert reference and all(c["verdict"] == "pass" for c in reference)  # blind to the bug
    warning = [line for line in run.stderr.splitlines() if "along the compared runs" in line]
    assert len(warning) == 1 and "C stayed below 1e-06 of its scale" in warning[0]
    assert "walls never touched" in warning[0]
    assert "exercised along the compared runs: none" in run.stdout
    names = {f["name"] for f in data["findings"] if f["case"] == "reference"}
    assert {"fall: exercised, C", "fall: exercised, F", "fall: exercised, walls"} <= names
