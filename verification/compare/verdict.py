r"""The verdict of ``mpmref compare``, frame by frame: does the code's run belong to the ensemble?

Two phases, decided by the ensemble alone (docs/comparing_runs.md):

**Round-off.** The ensemble's *spread* at a frame is :math:`s = \max_{k,p} \lVert x_p^{(k)} - x_p^{(0)}
\rVert_\infty`, the largest distance of a member's particle from the control's. While
:math:`s \le R = r\,\varepsilon L` (:math:`r` = :data:`ROUNDOFF_ULPS`, :math:`\varepsilon` the precision's epsilon,
:math:`L` the domain's extent), the runs differ by amplified round-off only, and the code's particles must agree with
the control's to the same degree: its *deviation* :math:`d = \max_p \lVert x_p^{code} - x_p^{(0)} \rVert_\infty` must
be at most :math:`K s` (:math:`K` = :data:`PARTICLE_FACTOR`). Once the spread passes :math:`R` the ensemble has left
round-off for good (the phase does not come back).

**Ensemble.** After that, particles of two correct runs part (contact and collisions amplify the last bit), and the
code's statistics (:mod:`.statistics`) must lie in the ensemble's distribution. Each statistic :math:`j` is
standardised by the ensemble's mean and standard deviation over its :math:`n` samples (the control and the members),
the deviation floored at its round-off :math:`r\,\varepsilon` times its scale: :math:`z_j`. Two tests, each
controlling its false alarms however correlated the statistics are:

* **principal components** (the ensemble consistency test of CESM: Baker et al. 2015, Milroy et al. 2018): the
  ensemble's standardised statistics are rotated to their principal components, and the code's scores on the
  :math:`k` leading ones (those carrying :data:`VARIANCE_KEPT` of the variance, at most :math:`n/4`), each divided by
  its standard deviation in the ensemble, give Hotelling's :math:`T^2 = \sum_{i \le k} t_i^2`. For a run drawn from
  the ensemble's (Gaussian) distribution, :math:`\frac{n}{n+1}\frac{n-k}{k(n-1)} T^2` follows Fisher's
  :math:`F(k, n - k)` (the prediction region of a new observation); the frame fails above its :math:`1 - \alpha'`
  quantile;
* **each statistic**: :math:`|z_j| / \sqrt{1 + 1/n}` follows Student's :math:`t_{n-1}` for such a run; the frame
  fails when the largest :math:`|z_j|` passes the two-sided :math:`1 - \alpha'/p` quantile (Bonferroni over the
  :math:`p` statistics). It sees a departure in a direction the ensemble does not vary in, which the leading
  components miss.

:math:`\alpha' = \alpha / (2 F)` splits the false-alarm rate :math:`\alpha` (:data:`ALPHA`) of a whole run between the
two tests and its :math:`F` frames (Bonferroni again), so many statistics and many frames do not multiply false
alarms. The statistics named at a failed frame are those past the per-statistic threshold (else the three largest
:math:`|z_j|`), with their materials.
"""

from dataclasses import dataclass, field

import numpy as np
from scipy import stats as distributions

#: the end of the round-off phase: the ensemble's spread, in units of epsilon times the domain's extent
ROUNDOFF_ULPS = 1024.0
#: in the round-off phase, the code's deviation may be this many times the ensemble's spread
PARTICLE_FACTOR = 10.0
#: the false-alarm rate of a whole comparison (every frame, both tests), for a run drawn from the ensemble
ALPHA = 0.01
#: the principal components kept carry this fraction of the ensemble's variance
VARIANCE_KEPT = 0.95
#: statistics named at a failed frame when none passes its own threshold
NAMED_AT_LEAST = 3


@dataclass(frozen=True)
class FrameLabel:
    """Which step (or time) a frame is: all the verdict reads of a frame."""

    step: int | None
    time: float | None


@dataclass
class FrameVerdict:
    """The judgement of one frame (module docstring).

    ``phase`` is ``"round-off"`` or ``"ensemble"``; ``spread`` and ``deviation`` the ensemble's and the code's
    largest particle distance from the control; ``z`` each statistic's standardised departure; ``t2``, ``t2_limit``
    and ``components`` the principal-component test (``None`` in the round-off phase), ``z_limit`` the per-statistic
    threshold; ``left`` the statistics named, ``[(name, z)]``."""

    index: int
    step: int | None
    time: float | None
    phase: str
    spread: float
    deviation: float
    particle_limit: float | None
    z: dict = field(repr=False)
    z_limit: float = np.inf
    t2: float | None = None
    t2_limit: float | None = None
    components: int = 0
    passed: bool = True
    left: list = field(default_factory=list)

    @property
    def label(self):
        return f"step {self.step}" if self.step is not None else f"t = {self.time:.6g}"

    def materials(self):
        """The materials of the statistics named, in order of first appearance."""
        return list(dict.fromkeys(name.split(":")[0] for name, _ in self.left))

    def reason(self):
        """Why the frame failed, in words (``""`` if it passed)."""
        if self.passed:
            return ""
        if self.phase == "round-off":
            start = " (at step 0: the code did not start from the exported start)" if self.step == 0 else ""
            return (f"particles {self.deviation:.3g} from the control, more than {PARTICLE_FACTOR:g} x the ensemble's "
                    f"round-off spread {self.spread:.3g}{start}")
        parts = []
        if self.t2 > self.t2_limit:
            parts.append(f"T^2 = {self.t2:.3g} > {self.t2_limit:.3g} on {self.components} principal components")
        worst = max(np.abs(list(self.z.values())), default=0.0)
        if worst > self.z_limit:
            parts.append(f"|z| = {worst:.3g} > {self.z_limit:.3g}")
        return "; ".join(parts)


def standardised(samples, code, floor):
    """``(z of the samples (n, p), z of the code (p,), standard deviations (p,))``: each statistic centred on the
    samples' mean and divided by their standard deviation, at least ``floor``."""
    mean = samples.mean(axis=0)
    sigma = np.maximum(samples.std(axis=0, ddof=1), floor)
    return (samples - mean) / sigma, (code - mean) / sigma, sigma


def hotelling(z_samples, z_code, alpha):
    r"""``(T^2, its limit at level alpha, k)``: the code's Hotelling :math:`T^2` on the :math:`k` leading principal
    components of the standardised samples, and the :math:`1 - \alpha` quantile of its distribution for a run drawn
    from theirs (module docstring)."""
    n = len(z_samples)
    _, singular, rotation = np.linalg.svd(z_samples, full_matrices=False)
    variance = singular**2
    if variance.sum() <= 0.0:
        return 0.0, np.inf, 0
    share = np.cumsum(variance) / variance.sum()
    k = int(min(np.searchsorted(share, VARIANCE_KEPT) + 1, max(1, n // 4), np.count_nonzero(variance)))
    scores = rotation[:k] @ z_code / (singular[:k] / np.sqrt(n - 1))
    t2 = float(scores @ scores)
    f = distributions.f.ppf(1.0 - alpha, k, n - k)
    return t2, float(f * k * (n - 1) / (n - k) * (n + 1) / n), k


def z_limit(n, p, alpha):
    r"""The largest :math:`|z_j|` of ``p`` statistics that a run drawn from ``n`` samples' distribution passes with
    probability :math:`1 - \alpha`: the Bonferroni bound with Student's :math:`t_{n-1}`, times
    :math:`\sqrt{1 + 1/n}`."""
    return float(distributions.t.ppf(1.0 - alpha / (2.0 * max(p, 1)), n - 1) * np.sqrt(1.0 + 1.0 / n))


def named(z, limit):
    """The statistics past ``limit``, largest first; the :data:`NAMED_AT_LEAST` largest if none is."""
    ranked = sorted(z.items(), key=lambda item: -abs(item[1]))
    past = [(k, v) for k, v in ranked if abs(v) > limit]
    return past or ranked[:NAMED_AT_LEAST]


def judge_frame(index, frame, samples, code, floor, names, spread, deviation, roundoff, alpha):
    """The :class:`FrameVerdict` of one frame: ``samples`` (n, p) the ensemble's statistics ``names``, ``code`` (p,)
    the code's, ``floor`` their round-off; ``roundoff`` whether the ensemble is still within round-off."""
    z_samples, z_code, _ = standardised(samples, code, floor)
    z = dict(zip(names, z_code.tolist()))
    limit = z_limit(len(samples), len(names), alpha)
    verdict = FrameVerdict(index, frame.step, frame.time, "round-off" if roundoff else "ensemble", float(spread),
                           float(deviation),
                           PARTICLE_FACTOR * spread if roundoff else None, z, limit)
    if roundoff:
        verdict.passed = bool(deviation <= PARTICLE_FACTOR * spread)
    else:
        verdict.t2, verdict.t2_limit, verdict.components = hotelling(z_samples, z_code, alpha)
        verdict.passed = verdict.t2 <= verdict.t2_limit and bool(np.all(np.abs(z_code) <= limit))
    if not verdict.passed:
        verdict.left = named(z, limit)
    return verdict


def judge(labels, measures):
    """The :class:`FrameVerdict` of every frame.

    ``labels`` say which step each frame is (:class:`FrameLabel`); ``measures`` (a
    :class:`~verification.compare.comparison.Measures`) holds the ensemble's statistics ``samples`` (frames, n, p),
    the ``code``'s (frames, p), their round-off ``floor`` (p,) and ``names``, the ensemble's and the code's particle
    distances from the control (``spreads``, ``deviations``) and the round-off limit :math:`R`."""
    m = measures
    alpha = ALPHA / (2.0 * len(labels))
    verdicts, roundoff = [], True
    for f, label in enumerate(labels):
        roundoff = roundoff and m.spreads[f] <= m.roundoff_limit
        verdicts.append(judge_frame(f, label, m.samples[f], m.code[f], m.floor, m.names, m.spreads[f],
                                    m.deviations[f], roundoff, alpha))
    return verdicts
