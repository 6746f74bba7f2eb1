"""The command line's small leaks: the GPU backend without a GPU is refused by every command that takes a
backend in the same one line with exit status 2, and a pass threshold out of its range is refused by name."""

from types import SimpleNamespace

import pytest

from mpmref.cli import main
from mpmref.conformance import check
from mpmref.errors import ArgumentError, BackendError

#: every command that takes a backend, each asking for the GPU backend
GPU_COMMANDS = {
    "run": ["run", "examples/mpm88.toml", "--backend", "cuda", "--steps", "1", "--out", "{out}"],
    "verify": ["verify", "momentum", "--quick", "--backend", "cuda", "--out", "{out}", "--no-progress"],
    "study": ["study", "examples/mpm88.toml", "--vary", "grid.cells=16,32", "--t-end", "0.001", "--backend", "cuda",
              "--out", "{out}", "--no-progress"],
    "conformance check": ["conformance", "check", "--backend", "cuda", "--no-progress"],
    "conformance check, atomic P2G": ["conformance", "check", "--backend", "mpmref.backends.cuda:atomic"],
    "bench": ["bench", "--backends", "numpy,cuda", "--size", "1000", "--json", "{out}/bench.json", "--no-progress"],
}


@pytest.fixture
def no_gpu(monkeypatch):
    """numba-cuda installed, but no GPU usable (whether or not this machine has one)."""
    from mpmref.backends.cuda import runtime

    absent = SimpleNamespace(implementation="NVIDIA", is_available=lambda: False,
                             cuda_error=lambda: "CUDA driver library cannot be found.")
    monkeypatch.setattr(runtime, "cuda", absent)
    monkeypatch.setattr(runtime, "simulated", lambda: False)


def run_command(words, out, capsys):
    status = main([word.format(out=out) for word in words])
    captured = capsys.readouterr()
    return status, captured.out, captured.err.strip().splitlines()


def test_every_command_refuses_the_gpu_backend_without_a_gpu_in_the_same_one_line(no_gpu, tmp_path, capsys):
    lines = {}
    for name, words in GPU_COMMANDS.items():
        out = tmp_path / name.replace(" ", "_").replace(",", "")
        out.mkdir()
        status, stdout, stderr = run_command(words, out, capsys)
        assert (status, stdout, len(stderr)) == (2, "", 1), (name, stdout, stderr)
        assert not any(out.iterdir()), name  # refused before any work
        lines[name] = stderr[0]
    assert len(set(lines.values())) == 1, lines
    assert "'cuda' needs a CUDA GPU" in lines["run"] and "CUDA driver library cannot be found" in lines["run"]


def test_the_harness_refuses_the_gpu_backend_without_a_gpu_before_any_case(no_gpu):
    with pytest.raises(BackendError, match="'cuda' needs a CUDA GPU"):
        check("cuda")


def test_conformance_export_takes_no_backend_and_says_so_in_one_line(tmp_path, capsys):
    status, stdout, stderr = run_command(["conformance", "export", str(tmp_path / "v"), "--backend", "cuda"],
                                         tmp_path, capsys)
    assert (status, stdout, len(stderr)) == (2, "", 1) and "unrecognized arguments: --backend cuda" in stderr[0]
    assert not (tmp_path / "v").exists()


@pytest.mark.parametrize("rtol", ["-1", "0", "-0.0", "nan", "inf", "-inf"])
def test_conformance_check_refuses_a_threshold_that_is_not_a_finite_positive_number(rtol, capsys):
    status, stdout, stderr = run_command(["conformance", "check", "--backend", "numpy", f"--rtol={rtol}"], "", capsys)
    assert (status, stdout, len(stderr)) == (2, "", 1)
    assert "argument --rtol" in stderr[0] and "a finite number > 0" in stderr[0]


@pytest.mark.parametrize("rtol", [-1.0, 0, float("nan"), float("inf"), True])
def test_the_harness_refuses_a_threshold_that_is_not_a_finite_positive_number(rtol):
    with pytest.raises(ArgumentError, match=r"rtol = .* allowed a finite number > 0"):
        check("numpy", [], rtol=rtol)


def test_conformance_check_takes_a_positive_threshold(capsys):
    status, stdout, _ = run_command(["conformance", "check", "--backend", "numpy", "--dim", "2", "--stage", "stress",
                                     "--rtol", "1e-10", "--no-progress", "--verbose"], "", capsys)
    assert status == 0 and "1e-10" in stdout
