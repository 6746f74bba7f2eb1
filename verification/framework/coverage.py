r"""What a run exercised: the fields and regimes a comparison along it could see, and those it could not.

A comparison of two codes along a run sees a wrong field only where the run makes it matter. A block in free fall
keeps :math:`C_p \approx 0` and :math:`F_p = I`: a code whose :math:`C` is 25 % wrong agrees with the reference to
round-off along it. ``mpmref verify --scene`` says, beside its verdict, what its runs exercised
(:func:`exercised`), and warns about each declared field or feature that they did not
(:func:`not_exercised`): "C stayed below 1e-6 of its scale; walls never touched".

Each item is measured on the states the checks compared (the kept states of the scene's run), against a scale of
its own:

* ``C``: :math:`\max_p |C_p|\,\Delta x / \max_p |v_p|`, the velocity an affine field adds across a cell against the
  particles' speed (the wave speed where they are at rest);
* ``F``, ``J``: :math:`\max_p \|F_p - I\|_F`, :math:`\max_p |J_p - 1|`: how far from the undeformed state;
* ``modes`` (PolyPIC): :math:`\max_p \|c_p\|` of the higher modes, over the speed scale;
* ``plastic flow``: :math:`\max_p |\ln J_{P,p}|`, where a plastic material is declared: whether a return map
  projected anything;
* ``walls``: the number of particles whose stencil reaches the band of an acting wall (not ``open``);
* ``colliders``: the number of particles whose stencil reaches inside a collider.

An item counts as exercised when its figure exceeds :data:`FLOOR` (walls and colliders: when one particle reaches
them). The floor is far above round-off (:math:`10^{-16}`) and far below any motion a check could see.
"""

from dataclasses import dataclass

import numpy as np

from mpmref.physics.kernels import compute_stencil
from mpmref.physics.materials import evolved_fields

#: a figure at or below this fraction of its scale did not exercise its field
FLOOR = 1.0e-6


@dataclass(frozen=True)
class Exercise:
    """One field or feature of a run: its ``name``, its ``figure`` (against its scale; a count for walls and
    colliders), whether the run ``exercised`` it and a ``sentence`` saying so."""

    name: str
    figure: float
    exercised: bool
    sentence: str


def exercised(scene, states):
    """The :class:`Exercise` of each field and feature of ``scene`` over ``states`` (states of its run,
    :class:`~mpmref.state.State`, or bare :class:`~mpmref.state.Particles` at time 0): ``C`` (affine schemes),
    ``modes`` (PolyPIC), ``F``, ``J``, ``plastic flow`` (where a material carries them), ``walls`` (where one acts),
    ``colliders`` (where the scene has some). A run that sees every step gives them to a :class:`Tracker`."""
    tracker = Tracker(scene)
    for state in states:
        tracker.see(state)
    return tracker.items()


class Tracker:
    """The largest figure of each item of :func:`exercised` over the states it has seen (:meth:`see`, each step of a
    run, or a sample of them), and the items (:meth:`items`)."""

    def __init__(self, scene):
        self.scene = scene
        carried = {f for m in scene.material_list for f in evolved_fields(m)}
        self.acting = [name for name, w in scene.boundary.walls.items() if w.type != "open"]
        wanted = {"C": scene.transfer.affine, "modes": scene.transfer.polypic, "F": "F" in carried,
                  "J": "J" in carried, "plastic flow": "Jp" in carried, "walls": bool(self.acting),
                  "colliders": bool(scene.colliders), "speed": True}
        self.largest = {name: 0.0 for name, present in wanted.items() if present}

    def see(self, state):
        """Take the figures of one state (a :class:`~mpmref.state.State` or bare particles at time 0)."""
        time, p = getattr(state, "time", 0.0), getattr(state, "particles", state)
        dim = self.scene.dim
        figures = {"C": lambda: _largest(p.C), "modes": lambda: _largest(p.modes),
                   "F": lambda: _largest(p.F - np.eye(dim)), "J": lambda: _largest(p.J - 1.0),
                   "plastic flow": lambda: _largest(np.log(p.Jp)),
                   "walls": lambda: _near_walls(self.scene, p, self.acting),
                   "colliders": lambda: _in_colliders(self.scene, p, time),
                   "speed": lambda: float(np.max(np.linalg.norm(p.v, axis=1), initial=0.0))}
        for name in self.largest:
            self.largest[name] = max(self.largest[name], figures[name]())

    def items(self):
        """The :class:`Exercise` of each item, against its scale (module docstring)."""
        largest, dx = self.largest, self.scene.grid.dx
        speed = largest["speed"] if largest["speed"] > 0.0 else self.scene.max_wave_speed()
        made = {"C": lambda: _field("C", largest["C"] * dx / speed, "|C| dx / |v|, the affine field's velocity "
                                    "across a cell against the particles' speed"),
                "modes": lambda: _field("modes", largest["modes"] / speed, "PolyPIC's higher modes against the "
                                        "particles' speed"),
                "F": lambda: _field("F", largest["F"], "|F - I|"), "J": lambda: _field("J", largest["J"], "|J - 1|"),
                "plastic flow": lambda: _field("plastic flow", largest["plastic flow"], "|ln J_P|: what the return "
                                               "maps moved into the plastic part"),
                "walls": lambda: _count("walls", largest["walls"], "particles whose stencil reaches the band of an "
                                        f"acting wall ({', '.join(self.acting)})"),
                "colliders": lambda: _count("colliders", largest["colliders"], "particles whose stencil reaches "
                                            "inside a collider")}
        return [made[name]() for name in largest if name != "speed"]


def not_exercised(items):
    """One sentence naming what ``items`` (:func:`exercised`) did not exercise, or ``""``: e.g. "C stayed below 1e-6 of
    its scale; walls never touched"."""
    parts = [f"{i.name} stayed below {FLOOR:g} of its scale" if i.name not in ("walls", "colliders")
             else f"{i.name} never touched" for i in items if not i.exercised]
    return "; ".join(parts)


def _field(name, figure, what):
    figure = float(figure)
    done = figure > FLOOR
    word = "exercised" if done else f"not exercised (at most {FLOOR:g} of its scale: a wrong {name} would not show)"
    return Exercise(name, figure, done, f"{name}: {what} reached {figure:.3g}, {word}")


def _count(name, count, what):
    done = count > 0
    return Exercise(name, float(count), done, f"{name}: {what}: {count:g}" + ("" if done else ", never touched"))


def _largest(a):
    return 0.0 if a is None or a.size == 0 else float(np.max(np.abs(a)))


def _near_walls(scene, particles, acting):
    """The particles whose stencil holds a node of an acting wall's band (nodes ``0 .. width-1`` from the lower face,
    ``cells-width+1 .. cells`` from the upper one)."""
    if particles.n == 0:
        return 0
    grid, width = scene.grid, scene.boundary.width
    stencil = compute_stencil(scene.kernel, particles.x.astype(np.float64), grid.origin, grid.dx)
    low, high = stencil.base, stencil.base + stencil.w.shape[2] - 1
    near = np.zeros(particles.n, dtype=bool)
    for a in range(scene.dim):
        if f"{'xyz'[a]}_min" in acting:
            near |= low[:, a] < width
        if f"{'xyz'[a]}_max" in acting:
            near |= high[:, a] > grid.cells[a] - width
    return int(near.sum())


def _in_colliders(scene, particles, time):
    """The particles within a stencil's reach (its support times :math:`\\sqrt d` cells) of a collider's inside at
    ``time``."""
    reach = scene.kernel.support * scene.grid.dx * np.sqrt(scene.dim)
    x = particles.x.astype(np.float64)
    inside = np.zeros(particles.n, dtype=bool)
    for collider in scene.colliders:
        inside |= collider.shape.sdf(x - collider.velocity * time) <= reach
    return int(inside.sum())
