"""Stability guard: the measured stable CFL limits, the step-1 warning and the boundedness check.

Provenance of :data:`MEASURED_LIMITS`: ``docs/stability.md``, section "Measured limits", produced by
``mpmref verify extremes --full`` (``verification/extremes.py``: a fixed-corotated block with a shear
plus noise at Mach 0.05 on a 16 × 16 grid, quadratic kernel, slip walls, 80 steps, 8 bisections,
resolution 0.011, numpy backend). Each entry is the largest CFL number
:math:`C = \\Delta t\\,(c + |v|_{max})/\\Delta x` at which the scheme stayed stable under that condition.
``pic`` and ``apic`` were measured with the classic force, ``flip`` with α = 0.95, ``mls`` and
``polypic`` with the MLS force. Young's modulus does not move the limits (E = 1e2 … 1e9 give the base row
to every digit, as dimensional analysis requires). Near the limit the energy grows slowly, so the
limits are fragile: measured again in a later version they moved (cause not identified); the guard uses
each scheme's smallest limit over the conditions, which moved least (docs/stability.md says by how much).

Why a warning and not a refusal at scene build: the limits are measured on one probe, and a run above
them is not always unstable (a block translating at 10 wave speeds is stable at C = 1.5, and
``mpmref verify extremes`` must run beyond the limits to find them). The CFL number also depends on the
particles' initial speed, known only once the bodies are sampled. So a fixed Δt whose CFL number
exceeds the limit is reported at step 1 with the number (:func:`warn_if_above_limit`), and the run
goes on under the boundedness check (:func:`first_unbounded`): the first unbounded step is warned about,
and a blow-up is stopped as an :class:`~mpmref.errors.InstabilityError` (with step, particle, quantity
and CFL number) when it turns non-finite or carries particles out of the domain, before any domain-exit
policy sees them. The last good state saved is the last one that a bounded, finite step produced.
"""

import warnings

import numpy as np

#: largest stable CFL number per condition and scheme (docs/stability.md, "Measured limits")
MEASURED_LIMITS = {
    "base (E = 1e4, nu = 0.3, ppc = 4)": {"pic": 1.228, "flip": 1.249, "apic": 1.682, "mls": 1.344, "polypic": 1.281},
    "nu = 0.4": {"pic": 1.597, "flip": 1.734, "apic": 1.429, "mls": 1.218, "polypic": 1.239},
    "nu = 0.45": {"pic": 1.291, "flip": 1.703, "apic": 1.376, "mls": 1.661, "polypic": 1.175},
    "nu = 0.49": {"pic": 1.239, "flip": 1.302, "apic": 1.576, "mls": 1.186, "polypic": 1.650},
    "nu = 0.499": {"pic": 1.545, "flip": 1.671, "apic": 1.566, "mls": 1.186, "polypic": 1.091},
    "E = 1e2, 1e6, 1e9": {"pic": 1.228, "flip": 1.249, "apic": 1.682, "mls": 1.344, "polypic": 1.281},
    "ppc = 1": {"pic": 0.912, "flip": 0.901, "apic": 0.964, "mls": 1.038, "polypic": 1.028},
    "ppc = 9": {"pic": 1.481, "flip": 1.555, "apic": 1.523, "mls": 1.597, "polypic": 1.429},
    "ppc = 16": {"pic": 2.051, "flip": 1.545, "apic": 1.597, "mls": 2.051, "polypic": 1.460},
}

#: a velocity change that alone would move a particle more than this many cells in one step is unbounded
MAX_CELLS_PER_STEP = 1.0


class StabilityWarning(UserWarning):
    """A fixed time step whose CFL number exceeds the scheme's measured stable limit."""


def stable_cfl(scheme):
    """The CFL number up to which ``scheme`` was stable in every measured condition (the table's minimum)."""
    return min(row[scheme] for row in MEASURED_LIMITS.values())


def above_limit_text(scheme, cfl):
    """A phrase saying that ``cfl`` exceeds the measured limit of ``scheme``, or ``""`` if it does not."""
    limit = stable_cfl(scheme)
    if not cfl > limit:
        return ""
    return f"above {limit}, the largest at which scheme '{scheme}' was stable in every measured condition " \
           "(docs/stability.md)"


def warn_if_above_limit(scene, cfl):
    """Warn (:class:`StabilityWarning`) when the scene's fixed ``time.dt`` gives a CFL number above the limit.

    Parameters
    ----------
    scene : Scene
    cfl : float    the CFL number of the first step
    """
    text = above_limit_text(scene.method.scheme, cfl)
    if scene.time.dt is None or not text:
        return
    safe_dt = scene.time.dt * stable_cfl(scene.method.scheme) / cfl
    warnings.warn(f"step 1: the CFL number of time.dt = {scene.time.dt:g} is {cfl:.5g}, {text}; a time.dt of at "
                  f"most {safe_dt:.3g} keeps it below", StabilityWarning, stacklevel=3)


def within_margin(largest, dim, dt, dx):
    r"""Whether a step whose largest velocity change in one component is ``largest`` is bounded without looking
    closer: :math:`|\Delta v| \le \sqrt d\,\max_a|\Delta v_a|`, so the change is bounded when
    :math:`\sqrt d\,\max_a|\Delta v_a|\,\Delta t/\Delta x` is at most half of :data:`MAX_CELLS_PER_STEP` (the
    margin of 2 covers the rounding of the dtype's subtraction). :func:`first_unbounded` looks closer otherwise, and
    a resident run (:mod:`mpmref.backends.residency`) takes ``largest`` from its summary."""
    return largest * np.sqrt(dim) * (dt / dx) <= 0.5 * MAX_CELLS_PER_STEP


def first_unbounded(v_old, v_new, dt, dx):
    r"""The first particle whose velocity change in one step is unbounded, with that change in cells.

    A change is unbounded when :math:`|v_p^{n+1} - v_p^n|\,\Delta t > \Delta x`: the change alone would
    carry the particle more than a cell in one step. A stable step changes a velocity by a small fraction
    of :math:`\Delta x/\Delta t`: gravity by :math:`g\Delta t`, a wall by at most the particle's own
    speed, which crosses a cell per step only beyond every measured CFL limit. A particle that merely moves
    fast is not flagged: a translating block is exact at any speed (docs/stability.md).

    Parameters
    ----------
    v_old, v_new : (n, d) arrays   velocities before and after the step
    dt, dx : float                 time step and cell size

    Returns
    -------
    (int, float) or None
        The particle index and :math:`|\Delta v|\,\Delta t/\Delta x`, or ``None`` when every change is bounded.
    """
    if v_new.size == 0:
        return None
    largest = float(np.max(np.abs(v_new - v_old)))
    if not np.isfinite(largest) or within_margin(largest, v_new.shape[1], dt, dx):
        return None  # non-finite is not ours
    jump = np.sqrt(np.sum((v_new.astype(np.float64) - v_old) ** 2, axis=1)) * (dt / dx)
    bad = jump > MAX_CELLS_PER_STEP
    if not bad.any():
        return None
    first = int(np.argmax(bad))
    return first, float(jump[first])
