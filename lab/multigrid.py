"""The multigrid Poisson solve's cycle and smoother, compared on the benchmark dress's own systems.

    python -m lab.multigrid                       # 156K and 1M triangles (78,490 and 501,758 vertices)
    python -m lab.multigrid --sizes 156000 --repeats 5

For each size, the dress's Poisson matrix and the right-hand sides and starts of a real cold transfer
(``lab.bench``), solved for the three coordinates to ``poisson.MULTIGRID_TOLERANCE``:

- pyamg's own cycle with its default smoother (symmetric Gauss-Seidel), the three coordinates one after
  the other (the solver before ``poisson.Multigrid``);
- ``poisson.Multigrid`` (our cycle and conjugate gradients, Chebyshev smoother) on one thread;
- the same, the three coordinates on threads at once (as ``PoissonSolver.solve`` runs them).

It prints the hierarchy's build time, the best solve time over the repeats, the iterations per
coordinate and the largest difference from the first answer relative to the garment's size.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np


def systems(triangles):
    """The Poisson matrix (n,n), right-hand sides (3,n) and starts (3,n) of a cold transfer of the
    benchmark dress of ``triangles`` triangles."""
    from garment_transfer.geometry import poisson

    from .bench import bench_bodies, tube_dress
    from .speed import _transfer

    seen = {}
    iterate = poisson.PoissonSolver._iterate

    def spy(self, rhs, start):
        seen.setdefault("rhs", []).append(rhs.copy())
        seen.setdefault("start", []).append(start.copy())
        seen["K"] = self.K
        return iterate(self, rhs, start)

    source, bodies = bench_bodies(1)
    garment = tube_dress(source, triangles)
    poisson.PoissonSolver._iterate = spy
    try:
        _transfer(source, bodies[0], garment)        # cold, one target: multigrid from 40K vertices
    finally:
        poisson.PoissonSolver._iterate = iterate
    return seen["K"], np.array(seen["rhs"]), np.array(seen["start"])


def compare(K, R, S, repeats):
    import pyamg

    from garment_transfer.geometry import poisson

    tol = poisson.MULTIGRID_TOLERANCE

    def pyamg_solve(ml, c):
        residuals = []
        x = ml.solve(R[c], x0=S[c].copy(), tol=tol, accel="cg", maxiter=200, residuals=residuals)
        return x, len(residuals)

    def ours_solve(ml, c):
        residuals = []
        return ml.solve(R[c], x0=S[c], tol=tol, maxiter=200, residuals=residuals), len(residuals)

    def build_pyamg():
        return pyamg.smoothed_aggregation_solver(K, symmetry="hermitian", strength=("symmetric", {"theta": 0.0}),
                                                 improve_candidates=None)

    rows, reference = [], None
    variants = [("pyamg cycle, Gauss-Seidel", build_pyamg, pyamg_solve, 1),
                ("ours, Chebyshev, one thread", lambda: poisson.Multigrid(K), ours_solve, 1),
                ("ours, Chebyshev, three threads", lambda: poisson.Multigrid(K), ours_solve, 3)]
    for name, build, solve, threads in variants:
        t = time.perf_counter()
        ml = build()
        setup = time.perf_counter() - t
        best = np.inf
        for _ in range(repeats):
            t = time.perf_counter()
            if threads == 1:
                out = [solve(ml, c) for c in range(3)]
            else:
                with ThreadPoolExecutor(threads) as pool:
                    out = list(pool.map(lambda c: solve(ml, c), range(3)))
            best = min(best, time.perf_counter() - t)
        X = np.column_stack([o[0] for o in out])
        reference = X if reference is None else reference
        rows.append((name, setup, best, [o[1] for o in out], float(np.abs(X - reference).max() / np.ptp(reference))))
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[156000, 1000000])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    for n in args.sizes:
        K, R, S = systems(n)
        print(f"{n} triangles, {K.shape[0]} vertices")
        for name, setup, best, iterations, diff in compare(K, R, S, args.repeats):
            print(f"  {name:32s} hierarchy {setup:6.3f} s  solve {best:6.3f} s  iterations {iterations}  "
                  f"difference {diff:.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
