"""One fitting mechanism (mpmref/backends/fitting.py): every axis of a scene chosen from a declaration together.

* Any declaration mpmref can model gets a probe scene it implements (hypothesis over declarations unlike ours); one it
  cannot model is named by :func:`unmodelable`, and the fit says why it has no scene.
* The method is chosen jointly: a kernel is never given to a scheme the validator refuses it with.
* A stand-in material keeps the density and the rest P-wave speed (each class makes its parameters for a speed), and
  the same law keeps its own parameters, given only those the backend fixes.
* The 3D slab of a 2D scene holds the 2D particles in every layer, with the 2D velocity field and the mass per depth.
"""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mpmref import Scene, SceneBuilder
from mpmref.backends.capabilities import (
    COLLIDER_SHAPES,
    DTYPES,
    EVOLVED,
    SCHEMES,
    WALL_TYPES,
    Implements,
    material_type,
)
from mpmref.backends.fitting import (
    ANYTHING,
    SLAB_CELLS,
    Allow,
    Inapplicable,
    fit,
    implemented_methods,
    implements_material,
    lifted,
    stand_in,
    unmodelable,
)
from mpmref.physics.catalogue import MATERIALS
from mpmref.physics.kernels import KERNELS
from mpmref.physics.materials import evolved_fields
from mpmref.scene.sampling import sample_particles


def probe(dim=2):
    return (SceneBuilder(dim=dim, name="probe").grid(size=1.0, cells=8)
            .material("solid", type="fixed_corotated", E=1.0e3, nu=0.3, rho=1.0)
            .box("solid", lower=[0.25] * dim, upper=[0.75] * dim).time(dt=1.0e-3, steps=1).build())


def subset(values):
    return st.lists(st.sampled_from(values), min_size=1, max_size=len(values), unique=True).map(tuple)


declarations = st.builds(Implements, dims=subset((2, 3)), schemes=subset(SCHEMES), forces=subset(("mls", "classic")),
                         kernels=subset(tuple(KERNELS)), materials=subset(tuple(MATERIALS)), walls=subset(WALL_TYPES),
                         friction=st.booleans(), colliders=st.just(()) | subset(COLLIDER_SHAPES),
                         dtypes=subset(DTYPES), evolves=st.lists(st.sampled_from(EVOLVED), unique=True).map(tuple),
                         stepping=st.just(("sync",)), rigid_bodies=st.booleans())


def modelable(declaration):
    """A method it implements (with the fields the transfer carries) and a material whose fields it evolves."""
    kinds = [MATERIALS[k] for k in declaration.materials]
    return bool(implemented_methods(declaration)) and any(
        set(evolved_fields(cls(**stand_in_parameters(cls)))) <= set(declaration.evolves) for cls in kinds)


def stand_in_parameters(cls):
    return {k: v for k, v in cls.with_wave_speed(1.0, 10.0, {}).items()}


@settings(max_examples=300)
@given(declarations)
def test_every_declaration_mpmref_can_model_gets_a_probe_it_implements(declaration):
    if modelable(declaration):
        fitted = fit(probe(), declaration, ANYTHING)
        assert declaration.missing(fitted.scene) == []
        assert fitted.scene.dim in declaration.dims
    else:
        with pytest.raises(Inapplicable) as info:
            fit(probe(), declaration, ANYTHING)
        assert info.value.reasons


@given(declarations)
def test_a_method_is_never_one_the_validator_refuses(declaration):
    """Every method the fit may choose is one a scene can declare: APIC, PolyPIC and MLS-MPM never get the linear
    hat, the MLS force never gets it either."""
    for scheme, force, gradient, kernel in implemented_methods(declaration):
        if kernel == "linear":
            assert scheme in ("pic", "flip") and force == gradient == "classic"


def test_apic_with_only_the_linear_hat_is_named_and_has_no_scene():
    declaration = Implements(schemes=("apic",), kernels=("linear",))
    (line,) = unmodelable(declaration)
    assert "apic scheme with the linear kernel" in line and "constant inertia D_p" in line
    with pytest.raises(Inapplicable):
        fit(probe(), declaration, ANYTHING)
    assert unmodelable(Implements()) == []  # a product of axes is not a claim that every combination exists


def test_the_kernel_follows_the_scheme_when_both_may_change():
    """The 88-line program's method on a code with PIC (linear hat) and APIC (quadratic): the fit keeps APIC and its
    quadratic kernel rather than give APIC the linear hat, which the validator refuses (the old axis-by-axis fit
    chose the kernel first)."""
    declaration = Implements(schemes=("pic", "apic"), forces=("classic", "mls"), kernels=("linear", "quadratic"))
    scene = SceneBuilder(dim=2).grid(size=1.0, cells=8).method("apic", kernel="cubic").material(
        "m", "fixed_corotated", E=1e3).box("m", lower=[0.3, 0.3], upper=[0.6, 0.6]).time(dt=1e-3).build()
    fitted = fit(scene, declaration, Allow(kernel=True)).scene
    assert (fitted.method.scheme, fitted.method.kernel) == ("apic", "quadratic")
    with pytest.raises(Inapplicable, match="needs the cubic kernel"):
        fit(scene, declaration, Allow())


@given(st.sampled_from(sorted(MATERIALS)), st.sampled_from(sorted(MATERIALS)), st.floats(0.5, 3000.0),
       st.floats(0.0, 0.45))
def test_a_stand_in_keeps_the_density_and_the_rest_wave_speed(kind, other, rho, nu):
    given_ = {"gamma": 1.0 + 10 * nu} if kind == "fluid" else {"nu": nu}
    material = MATERIALS[kind](**MATERIALS[kind].with_wave_speed(rho, 25.0, given_))
    declaration = Implements(materials=(other,))
    spec = stand_in(material, declaration, "any")
    assert spec is not None and spec["type"] == other
    made = MATERIALS[other](**{k: v for k, v in spec.items() if k != "type"})
    assert made.rho == rho and made.wave_speed() == pytest.approx(material.wave_speed(), rel=1e-12)
    assert implements_material(made, declaration) == (set(evolved_fields(made)) <= set(declaration.evolves))


def test_the_same_law_keeps_its_parameters_and_takes_only_the_fixed_ones():
    scene = Scene.from_toml("examples/snow88.toml")
    (snow,) = scene.material_list
    declaration = Implements(parameters={"snow": {"Jp_min": 1e-300, "Jp_max": 1e300}})
    spec = stand_in(snow, declaration, "substitute")
    assert spec == {"type": "snow", "rho": snow.rho, "E": snow.E, "nu": snow.nu, "theta_c": snow.theta_c,
                    "theta_s": snow.theta_s, "hardening": snow.hardening, "Jp_min": 1e-300, "Jp_max": 1e300}
    fitted = fit(scene, declaration, Allow(materials="substitute"))
    assert "given the parameters the backend fixes: Jp_min = 1e-300 for 0.6, Jp_max = 1e+300 for 20" in \
        fitted.changes[0]
    with pytest.raises(Inapplicable, match="needs snow Jp_min = 0.6"):
        fit(scene, declaration, Allow())


def test_the_slab_holds_the_2d_particles_in_every_layer_with_their_velocity_field():
    scene = Scene.from_toml("examples/colliding_disks.toml")
    flat = sample_particles(scene)
    slab = Scene.from_dict(lifted(scene), base_dir=scene.base_dir)
    deep = sample_particles(slab)
    layers = deep.n // flat.n
    assert slab.dim == 3 and deep.n == layers * flat.n and layers == SLAB_CELLS * 2  # ppc 4: 2 per axis
    for body in range(2):  # each body's particles, layer after layer
        mine, its = flat.x[:, 0] < 0.5 if body == 0 else flat.x[:, 0] >= 0.5, deep.x[:, 0] < 0.5 if body == 0 else \
            deep.x[:, 0] >= 0.5
        np.testing.assert_array_equal(deep.x[its, :2], np.tile(flat.x[mine], (layers, 1)))
        np.testing.assert_array_equal(deep.v[its, :2], np.tile(flat.v[mine], (layers, 1)))
    assert np.all(deep.v[:, 2] == 0.0)
    depth = SLAB_CELLS * scene.grid.dx
    assert deep.mass.sum() == pytest.approx(flat.mass.sum() * depth, rel=1e-13)  # the 2D mass is per unit depth
    assert abs(deep.x[:, 2].mean()) < 1e-15 * scene.grid.dx and np.ptp(deep.x[:, 2]) < depth
    assert {w.type for name, w in slab.boundary.walls.items() if name.startswith("z")} == {"open"}


def test_a_3d_only_code_gets_the_slab_when_the_claim_holds_in_any_dimension():
    scene = Scene.from_toml("examples/jelly.toml")
    declaration = Implements(dims=(3,))
    fitted = fit(scene, declaration, Allow(dims=True))
    assert fitted.scene.dim == 3 and "slab" in fitted.changes[0]
    with pytest.raises(Inapplicable, match="needs 2D"):
        fit(scene, declaration, Allow())
    with pytest.raises(Inapplicable, match="emitters has no 3D slab"):
        fit(Scene.from_toml("examples/sand_wheel2d.toml"), declaration, Allow(dims=True))


def test_material_type_reads_each_class():
    assert {material_type(cls(**stand_in_parameters(cls))) for cls in MATERIALS.values()} == set(MATERIALS)


def _case_allowances():
    """Every allowance a verification case fits its scenes with (each case's ``ALLOWS``, with and without the free
    force of a variant that does not name it)."""
    from dataclasses import replace

    from verification import backends, energy, extremes, momentum, transfer_energy
    from verification.convergence import ALLOWS as convergence
    from verification.energy_ledger import runs

    allows = [momentum.ALLOWS, energy.ALLOWS, runs.ALLOWS, runs.FRICTION_ALLOWS, backends.ALLOWS, extremes.ALLOWS,
              transfer_energy.ALLOWS, convergence, ANYTHING]
    return allows + [replace(a, force=True) for a in allows]


EXAMPLES = sorted(str(p) for p in (Path(__file__).resolve().parent.parent / "examples").glob("*.toml"))


@settings(max_examples=60)
@given(declarations, st.sampled_from(EXAMPLES), st.sampled_from(_case_allowances()))
def test_any_declaration_fits_any_example_with_any_cases_allowance_or_says_why(declaration, path, allow):
    """The fit never errs: a scene the backend implements, or :class:`Inapplicable` with reasons (every example,
    every case's allowance, declarations unlike ours)."""
    scene = Scene.from_toml(path)
    try:
        fitted = fit(scene, declaration, allow)
    except Inapplicable as exc:
        assert exc.reasons and all(isinstance(r, str) and r for r in exc.reasons)
        return
    assert declaration.missing(fitted.scene) == []
    assert fitted.changes or fitted.scene is scene
