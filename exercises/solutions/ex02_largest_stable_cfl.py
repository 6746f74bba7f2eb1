r"""Exercise 2: find the largest stable CFL number of a scheme by bisection.

Task. The CFL number :math:`C = \Delta t\,(c + |v|_{max})/\Delta x` (``docs/mpm_cycle.md``, "Time step")
measures the step against the time a wave needs to cross a cell. Explicit MPM is stable only below
some :math:`C^*` that depends on the scheme. Find :math:`C^*` for MLS-MPM and for PIC with the classic
force on the probe of ``verification/extremes.py`` (a sheared, noisy elastic block on 16 × 16 cells),
by bisection on "stable for 80 steps": no non-finite value, no particle leaving, total energy below 10
times its start.

Prediction. For symplectic Euler on a grid of springs, the limit is :math:`C^* \approx 1`; MPM's
B-spline stencil spreads a particle's stiffness over several nodes, so the limits should be of order
one, with MLS-MPM above PIC (``mpmref.run.stability.MEASURED_LIMITS`` orders them that way).

Worked solution. ``verification.extremes.is_stable`` runs the probe at one CFL number. Bisect between
0.3 (stable) and 3.0 (unstable) with eight halvings (resolution 0.0105). The result is the same
number that the verification case's own bisection reports: the procedure, not just the scheme,
defines a measured limit, since stability is not exactly monotone in :math:`C` near the edge.
"""

from verification.extremes import Bisection, Condition, Params, bisect, is_stable

PROBE = Params(steps=80, bisections=8)
BRACKET = (0.3, 3.0)


def largest_stable_cfl(scheme):
    item = Bisection(PROBE, scheme, Condition())
    lo, hi = BRACKET
    assert is_stable(item, lo)["stable"] and not is_stable(item, hi)["stable"], "the bracket does not bracket"
    for _ in range(PROBE.bisections):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if is_stable(item, mid)["stable"] else (lo, mid)
    return lo, hi


def solve():
    found = {scheme: largest_stable_cfl(scheme) for scheme in ("mls", "pic")}
    for scheme, (lo, hi) in found.items():
        assert 0.5 < lo < hi < 2.0, (scheme, lo, hi)
        assert lo == bisect(Bisection(PROBE, scheme, Condition()))["limit"], scheme
    assert found["mls"][0] > found["pic"][0], "MLS-MPM should tolerate a larger CFL number than PIC"
    return found


if __name__ == "__main__":
    print(solve())
