"""Shared builders for tests: small random particle states and scenes."""

from pathlib import Path

import numpy as np

from mpmref import Scene, SceneBuilder
from mpmref.physics.polypic import higher_modes
from mpmref.state import Particles


def box_scene(dim=2, scheme="apic", cells=16, material="fixed_corotated", walls="open", gravity=None,
              kernel="quadratic", force="mls", **time):
    b = SceneBuilder(dim=dim, name="t").grid(size=1.0, cells=cells).method(scheme, kernel=kernel, force=force)
    if material == "fluid":
        b.material("m", "fluid", K=400.0, gamma=1.0, rho=1.0)
    else:
        b.material("m", material, E=1e3, nu=0.3, rho=1.0)
    lo, hi = [0.3] * dim, [0.7] * dim
    b.box("m", lower=lo, upper=hi, ppc=2**dim)
    b.walls(walls)
    if gravity is not None:
        b.gravity(gravity)
    b.time(**(time or {"dt": 1e-4, "steps": 10}))
    return b.build()


def random_particles(scene, n, rng, affine_scale=1.0):
    """Particles at random positions well inside the grid with random v, C, F (det > 0) and J."""
    d = scene.dim
    lo, hi = scene.valid_region()
    x = lo + 0.1 + rng.random((n, d)) * (hi - lo - 0.2)
    eye = np.eye(d)
    return Particles(
        x=x, v=rng.standard_normal((n, d)), mass=0.5 + rng.random(n), vol0=(0.5 + rng.random(n)) * 1e-3,
        material=np.zeros(n, dtype=np.int32),
        C=affine_scale * rng.standard_normal((n, d, d)) if scene.transfer.affine else None,
        F=eye + 0.1 * rng.standard_normal((n, d, d)) if scene.tracks("F") else None,
        J=1.0 + 0.1 * rng.random(n) if scene.tracks("J") else None,
        Jp=1.0 + 0.1 * rng.random(n) if scene.tracks("Jp") else None,
        modes=affine_scale * rng.standard_normal((n, len(higher_modes(d, scene.kernel.support)), d))
        if scene.transfer.polypic else None,
    )


def valid_methods():
    """Every (scheme, force, kernel) that the scene rules accept, as keyword dicts."""
    from mpmref import SceneError
    from mpmref.physics.kernels import KERNELS
    from mpmref.scene import FORCES, SCHEMES

    out = []
    for scheme in SCHEMES:
        for force in FORCES:
            for kernel in KERNELS:
                try:
                    box_scene(2, scheme, kernel=kernel, force=force)
                except SceneError:
                    continue
                out.append({"scheme": scheme, "force": force, "kernel": kernel})
    return out


def fd_gradient(energy, F, h=1e-6):
    """Central finite difference dPsi/dF_ij of a batched energy (n, d, d) -> (n,)."""
    n, d, _ = F.shape
    P = np.zeros_like(F)
    for i in range(d):
        for j in range(d):
            dF = np.zeros_like(F)
            dF[:, i, j] = h
            P[:, i, j] = (energy(F + dF) - energy(F - dF)) / (2.0 * h)
    return P


def independent_lame(E_, nu_):
    """Lamé parameters written out independently of ``mpmref.physics.materials.lame_parameters``."""
    return E_ / (2.0 + 2.0 * nu_), E_ * nu_ / ((1.0 + nu_) * (1.0 - 2.0 * nu_))


def random_deformations(rng, n, dim, scale=0.3, min_det=0.3):
    """Deformation gradients I + scale * U(-1, 1) with det F > min_det (rejection sampling)."""
    out = []
    while len(out) < n:
        F = np.eye(dim) + scale * rng.uniform(-1.0, 1.0, size=(dim, dim))
        if np.linalg.det(F) > min_det:
            out.append(F)
    return np.array(out)


__all__ = ["box_scene", "random_particles", "valid_methods", "fd_gradient", "independent_lame", "random_deformations",
           "Scene", "assert_every_figure_has_a_caption"]


def assert_every_figure_has_a_caption(folder):
    """Every PNG under ``folder`` carries a caption (:func:`verification.framework.report.save_figure`) that reads as a
    sentence about the figure, not a file name."""
    from verification.framework.report import figure_caption

    pngs = sorted(Path(folder).rglob("*.png"))
    assert pngs, f"no figures under {folder}"
    for png in pngs:
        caption = figure_caption(png)
        assert caption is not None, f"{png.name} has no caption"
        assert "Look for" in caption and png.name not in caption and len(caption.split()) >= 15, caption


def full_and_resumed_runs(scene, folder, steps, stop_at):
    """``(full, resumed)``: ``scene`` run for ``steps`` in one go, and run to ``stop_at``, then resumed from
    its checkpoint in ``folder`` and run to the end. The particles must agree bit for bit (asserted here);
    the caller compares the state it cares about (stepper levels, rigid bodies)."""
    from mpmref import Simulation

    full = Simulation(scene, out_dir=folder / "full")
    full.run(steps=steps)
    Simulation(scene, out_dir=folder / "half").run(steps=stop_at)
    resumed = Simulation.resume(scene, folder / "half")
    resumed.run(steps=steps - stop_at)
    assert resumed.step_count == full.step_count == steps
    for name, arr in full.particles.arrays().items():
        assert np.array_equal(arr, getattr(resumed.particles, name)), name
    return full, resumed
