"""The scenes of the sync-vs-async case (:mod:`verification.sync_vs_async`): its parameters and the scenes its parts
run: the two bodies of the worked example, the colliding balls, the census's spinning ball and the pressed disks.
"""

from dataclasses import dataclass

from mpmref import SceneBuilder

SCHEDULE_DX = 1.0 / 16


@dataclass(frozen=True)
class Params:
    one_level_steps: int = 100
    free_fall_intervals: int = 6
    census_ticks: int = 10_000
    ball_cells: int = 32
    ball_E: float = 1e3
    ball_E_ratio: float = 100.0
    ball_speed: float = 1.0
    ball_t_end: float = 0.12
    stork_t_end: float = 0.02
    stork3d_t_end: float = 0.004
    stork3d_cells: int = 32
    frames: int = 6
    interfaces: tuple = ("conservative", "reference")
    isolated_intervals: int = 4
    bonded_cfls: tuple = (0.4, 0.2, 0.1, 0.05)
    series_cfls: tuple = (0.4, 0.2, 0.1, 0.05, 0.025)
    series_t_end: float = 0.04
    trade_cfls: tuple = (0.4, 0.2, 0.1)
    trade_levels: tuple = (2, 4, 7)
    trade_reference_division: int = 16
    trade_sync_divisions: tuple = (1, 2, 4)
    bonded_interfaces: tuple = ("conservative", "reference")
    series_finer_rows: int = 99  # rows of the balls' series that also run sync at a 4x finer step
    series_interfaces: tuple = ("conservative", "reference")

    @classmethod
    def quick(cls):
        return cls(census_ticks=10_000, ball_cells=24, ball_t_end=0.04, stork_t_end=0.002, stork3d_t_end=0.001,
                   stork3d_cells=24, frames=3, series_cfls=(),
                   series_t_end=0.03, trade_cfls=(0.4,), trade_levels=(4, 7), trade_reference_division=4,
                   trade_sync_divisions=(1, 2), bonded_interfaces=("conservative",), bonded_cfls=(0.4, 0.2),
                   series_finer_rows=1, series_interfaces=("conservative",))

    @classmethod
    def full(cls):
        return cls(ball_cells=64, ball_t_end=0.2, stork_t_end=0.05, stork3d_t_end=0.02, series_t_end=0.06)


def two_bodies(stepping="async", gravity=0.0, walls="slip", bonded=False, block=8, **time):
    """A stiff and a soft elastic square side by side (16 cells, blocks of ``block`` cells, 8 by default: the two
    blocks per axis of the worked example): 3 cells apart and moving apart, or ``bonded`` (touching, one body of
    two materials)."""
    d = SCHEDULE_DX
    soft_from = 6 * d if bonded else 9 * d
    b = (SceneBuilder(dim=2, name="two_bodies").grid(size=1.0, cells=16, block=block).method("mls")
         .material("soft", "fixed_corotated", E=1e3, nu=0.3, rho=10.0)
         .material("stiff", "fixed_corotated", E=1e5, nu=0.3, rho=10.0)
         .box("stiff", lower=[2 * d, 2 * d], upper=[6 * d, 6 * d], velocity=[-0.2, 0.1])
         .box("soft", lower=[soft_from, 2 * d], upper=[soft_from + 4 * d, 6 * d],
              velocity=[-0.2 if bonded else 0.2, 0.1])
         .gravity([0.0, gravity]))
    b.walls(type=walls)
    b.time(stepping=stepping, **time)
    return b.build()


def balls(params, stepping, **time):
    """Two elastic balls of stiffness E and E·ratio flying at each other (no gravity, slip walls)."""
    r, v = 0.12, params.ball_speed
    return (SceneBuilder(dim=2, name="balls").grid(size=1.0, cells=params.ball_cells).method("mls")
            .material("soft", "fixed_corotated", E=params.ball_E, nu=0.3, rho=10.0)
            .material("stiff", "fixed_corotated", E=params.ball_E * params.ball_E_ratio, nu=0.3, rho=10.0)
            .ball("soft", center=[0.5 - r - 0.02, 0.5], radius=r, velocity=[v, 0.0], ppc=4)
            .ball("stiff", center=[0.5 + r + 0.02, 0.52], radius=r, velocity=[-v, 0.0], ppc=4)
            .walls(type="slip").time(stepping=stepping, **time).build())


def census_scene():
    """The id census's scene: a spinning ball on four levels, on a 16-cell grid (:func:`~.levels.schedule`)."""
    return (SceneBuilder(dim=2).grid(size=1.0, cells=16, block=4).method("mls")
            .material("m", "fixed_corotated", E=50.0, nu=0.3, rho=1.0)
            .ball("m", center=[0.5, 0.5], radius=0.2, ppc=1, velocity=[0.6, -0.4], angular_velocity=3.0)
            .walls(type="separate").time(stepping="async", cfl=0.5, tick=1e-4, levels=4, steps=1).build())


def pressed_disks(interface="conservative", stepping="async", scheme="mls", method=None, intervals=1, **time):
    """A soft and a stiff disk (E ratio 100, levels three apart) pressed together by a cell and spinning, in free
    space (open walls, no gravity): nothing external acts on them. ``method`` holds extra ``[method]`` keys
    (e.g. ``flip_alpha``); ``intervals`` synchronised intervals; ``time`` the keys of a synchronous run."""
    b = (SceneBuilder(dim=2, name="pressed").grid(size=1.0, cells=20).method(scheme, **(method or {}))
         .material("soft", "fixed_corotated", E=1e3, nu=0.3, rho=10.0)
         .material("stiff", "fixed_corotated", E=1e5, nu=0.3, rho=10.0)
         .ball("soft", center=[0.38, 0.5], radius=0.13, velocity=[0.4, 0.1], angular_velocity=2.0)
         .ball("stiff", center=[0.62, 0.52], radius=0.13, velocity=[-0.4, 0.0], angular_velocity=-1.0)
         .walls("open"))
    if stepping == "async":
        return b.time(stepping="async", cfl=0.4, tick=1e-6, levels=10, steps=intervals, interface=interface).build()
    return b.time(**time).build()
