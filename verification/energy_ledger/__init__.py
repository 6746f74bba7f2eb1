r"""Energy ledger: where each example's energy goes, stage by stage, and the signs theory fixes, checked.

Runs (NumPy reference unless another backend is asked for; the ledger on, ``[output] energy_ledger``):

* **the examples** ``jelly`` (under each of the six schemes of the energy case), ``snow88``, ``sand``,
  ``colliding_disks``, ``cut2d`` (CPIC) and the asynchronous ``stork2d``, each under its own method. The quick and
  default presets skip the free flight before the first contact (each body moved along its free-fall path and given its
  velocity there, which every transfer reproduces exactly; :func:`~.runs.free_flight`) and run each example through its
  contact for a short span (:data:`~.runs.RUNS`); the quick preset also halves every grid. The full preset runs each
  example from rest to its own end time. The stork's ledger is read at its synchronised times and has one more term,
  ``interface`` (the exchanges across its level interfaces; zero in the synchronous runs); it is not compared
  with the candidate, whose comparison books one synchronous step.
* **the friction block**: an elastic block slides at 1 m/s on a ``separate`` floor with Coulomb friction
  :math:`\mu = 0.3` under :math:`g = 10`, 300 steps.
* **the integration study**: the energy case's oscillating jelly (MLS-MPM) to 0.01 s (quick: 0.005 s) at
  :math:`\Delta t`, :math:`\Delta t/2`, :math:`\Delta t/4` (full: and :math:`\Delta t/8`).
* **the candidate**: from each compared run's state half-way and at its end, one step booked on the reference and on
  the candidate (``numba``, or the backend named by ``--backend`` when it is not ``numpy``).

Each run's split of its energy change into the ledger's terms is tabulated (the report and ``results.json``),
drawn as stacked areas of the cumulative terms, and written per particle (the cumulative ``plastic`` and
``advection`` shares) into its VTK frames.

Theory and bounds
-----------------
:math:`S` is a run's energy scale, :math:`K + \Psi + |U| + |E_{bodies}|` at its largest over the run
(:func:`mpmref.observe.ledger.energy_scale`); round-off is :math:`10^{-12} S` per step (the error of a float64 sum of
:math:`N \le 9000` terms of one sign is at most :math:`N u S`, Higham 2002 §4.2).

* **The terms add up.** They telescope: their cumulative sum equals the change of total energy the diagnostics
  measure, to :math:`(n + 2) \cdot 10^{-12} S` after :math:`n` steps. A joule that leaves outside the step (a
  particle deleted at the domain's edge) would show here.
* **Transfers never add energy** for PIC, APIC, MLS-MPM and PolyPIC without rigid bodies, each step:
  ``p2g_transfer`` :math:`\le 10^{-12} S` (each node's momentum is a mass-weighted average of the particles'
  velocity fields: Cauchy–Schwarz) and ``g2p_transfer`` :math:`\le 10^{-12} S` (G2P projects the grid's velocity onto
  the particle's field in the weights' norm: a mean for PIC, mean and affine part for APIC with the constant
  :math:`D_p` of the quadratic and cubic kernels). FLIP's G2P adds the grid's increment and CPIC's uses ghost
  velocities: neither is a projection, and neither is checked.
* **PolyPIC's G2P keeps everything**: :math:`|\texttt{g2p\_transfer}| \le 10^{-12} S` each step (its :math:`S^d`
  modes represent any stencil velocity exactly, Fu et al. 2017 §5).
* **Static walls never add energy**: ``boundary`` :math:`\le 10^{-12} S` each step where walls or colliders act and
  none moves (:math:`R_i \cdot v_i \le 0` for every projection of talk Eq. 25).
* **Return maps dissipate**: ``plastic`` :math:`\le 10^{-12} S` each step with a plastic material. Sand's return
  map projects the Hencky strain onto the yield surface along the energy's gradient (Klar et al. 2016 §7.3). Snow's
  (Stomakhin et al. 2013) clamps the singular values, which lowers the energy, and hardens, which raises it: to
  first order in a step's overshoot :math:`\delta` past :math:`1 - \theta_c`, under a uniform compression, the
  clamp removes :math:`\propto \delta` and the hardening :math:`e^{\xi(1 - J_P)}` adds
  :math:`\xi J_P \theta_c / (1 - \theta_c)^2` of that, a net loss while that factor is below 1 (``snow88``:
  :math:`\xi \theta_c = 0.25`). Theory fixes snow's sign only that far; the check holds ``snow88`` to it.
* **Friction**: the floor takes :math:`\mu m g d` over the distance :math:`d` the block slides (the work of the
  friction force :math:`\mu m g`): ``boundary`` within 5 % of it.
* **The integration error is first order**: symplectic Euler's energy error is :math:`O(\Delta t^2)` per step
  (Hairer, Lubich & Wanner 2006, ch. IX), so :math:`\sum_n |\texttt{integration}_n|` to a fixed time is
  :math:`O(\Delta t)`: fitted slope within 0.2 of 1.
* **The candidate books what the reference books**: each term within :math:`10^{-12}` of the step's energy scale,
  the conformance bound (the ledger stage of :mod:`mpmref.conformance`).

Terms whose sign theory leaves open and that added energy over a run are findings (reported, not judged).

On a backend that implements a part (:mod:`verification.framework.applicable`): each run, the friction block and the
integration study run if the backend implements their scene, within what their claims allow: another hyperelastic
material it has (the same density and P-wave speed: the closure and every sign hold for any stored energy), a material
of its type with the parameters it fixes, open walls as its walls on a domain padded by their band (nothing reaches
them), an acting wall as a static wall it has and friction dropped (a static wall's projection, frictionless or not,
never adds energy), the kernel it has, its force where the run's scheme does not name one, and for a code without 2D
the 3D slab of the example (:func:`mpmref.backends.fitting.lifted`). The plastic examples on a code without their
material (snow88, sand: their claim is the return map's), CPIC (cut2d), asynchronous stepping (stork2d), and the
friction block where the backend has no friction, are not applicable to a backend without them. The candidate is the
backend itself, compared with the reference on the runs it implements.

The case is a package: :mod:`.runs` (its parameters, scenes and simulations) and :mod:`.reporting` (checks,
findings, tables and figures).
"""

from ..framework.applicable import Triage
from ..framework.case import VerificationCase
from ..framework.executor import Executor
from .reporting import checks, findings, report, tables
from .runs import ALLOWS, RUN, Params, candidate_of, compared_runs, example_scene, parts, run_part

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "ledger_terms.png"


def run(params=Params(), backend="numpy", executor=None):
    """Every run of the case that ``backend`` implements, the independent ones through ``executor`` (default: in this
    process); the compared runs book their steps on the candidate too (:func:`~.runs.run_example`). The friction block
    or the integration study, when not applicable, is ``None``."""
    triage = Triage(backend)
    jobs = parts(params, backend, triage)
    if not jobs:
        raise triage.nothing_ran()
    done = dict(zip(jobs, (executor or Executor(workers=1)).map(
        run_part, [(function, params, args, backend) for function, args in jobs.values()])))
    runs = [done[f"run/{key}"] for key in params.runs if f"run/{key}" in done]
    return {"params": params, "backend": backend, "candidate": candidate_of(params, backend), "runs": runs,
            "friction": done.get("friction"), "integration": done.get("integration"),
            "compared": {r["key"]: r["compared"] for r in runs if r["compared"]}, **triage.record()}


def backends_run(result, backend):
    """The backend the runs ran on, and the reference and candidate of the comparison."""
    return tuple(dict.fromkeys((backend, "numpy", result["candidate"]) if result["compared"] else (backend,)))


def compiled_scenes(params, backend="numpy"):
    """``[(backend, scene)]`` run on a backend other than the reference (:mod:`verification.framework.warmup`): on the
    reference, the compared runs' scenes on the candidate; on another backend, every run's (the friction block and the
    integration study run the kernels of the jelly under MLS-MPM)."""
    keys = compared_runs(params) if backend == "numpy" else params.runs
    candidate = candidate_of(params, backend)
    triage = Triage(candidate)
    scenes = [triage.scene(key, example_scene(RUN[key], params), ALLOWS) for key in keys]
    return [(candidate, scene) for scene in scenes if scene is not None]


#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings, backends_run=backends_run,
                        compiled_scenes=compiled_scenes, tables=tables, main_figure=MAIN_FIGURE)

__all__ = ["CASE", "MAIN_FIGURE", "Params", "backends_run", "checks", "compiled_scenes", "findings", "report", "run",
           "tables"]
