"""Preconditioners for the melt-pool simulator's Newton systems, side by side.

Runs one default simulation (``--case P v``, mid-range parameters), keeps the AMG
matrix ``M`` and right-hand side of the Newton steps picked by ``--steps`` (indices over
the run's Newton steps; negative ones count from the end, so ``-1`` is the fine solve's
last), and solves each ``M x = b`` to a relative residual of ``--rtol`` with GMRES and
several preconditioners (classical AMG as the simulator builds it and variants,
pyamg's AIR and smoothed aggregation, incomplete LU), and with SuperLU. Prints setup and
solve CPU seconds, GMRES iterations and the true relative residual per system.

Usage (repository root)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/melt_pool/linear_solvers.py \\
        --case 152 0.32 --steps 40 70 -12 -6
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import pyamg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from calnet.simulators import melt_pool
from calnet.simulators.melt_pool import solver

AMG = solver.LinearSolver.hierarchy  # the simulator's classical AMG, settings overridable
TWICE = {"presmoother": ("gauss_seidel", {"sweep": "forward", "iterations": 2}),
         "postsmoother": ("gauss_seidel", {"sweep": "backward", "iterations": 2})}
SYMMETRIC = {"presmoother": ("gauss_seidel", {"sweep": "symmetric"}),
             "postsmoother": ("gauss_seidel", {"sweep": "symmetric"})}


def _ilu(A: sp.csr_matrix) -> spla.LinearOperator:
    return spla.LinearOperator(A.shape, spla.spilu(A.tocsc(), drop_tol=1e-4,
                                                   fill_factor=5).solve)


# name -> preconditioner (a LinearOperator) built from the matrix
PRECONDITIONERS: dict[str, Callable[[sp.csr_matrix], spla.LinearOperator]] = {
    "classical AMG (simulator)": lambda A: AMG(A).aspreconditioner(),
    "classical AMG, splu coarse": lambda A: AMG(A, coarse_solver="splu").aspreconditioner(),
    "classical AMG, theta 0.5": lambda A: AMG(
        A, strength=("classical", {"theta": 0.5}), coarse_solver="splu").aspreconditioner(),
    "classical AMG, 2 sweeps": lambda A: AMG(A, coarse_solver="splu",
                                              **TWICE).aspreconditioner(),
    "classical AMG, symmetric GS": lambda A: AMG(A, coarse_solver="splu",
                                                  **SYMMETRIC).aspreconditioner(),
    "AIR": lambda A: pyamg.air_solver(A, max_coarse=400).aspreconditioner(),
    "smoothed aggregation, evolution": lambda A: pyamg.smoothed_aggregation_solver(
        A, strength="evolution", max_coarse=400, smooth=None).aspreconditioner(),
    "ILU (drop 1e-4, fill 5)": _ilu,
}


def capture(P: float, v: float) -> list[tuple[sp.csr_matrix, np.ndarray, int, float]]:
    """``(M, b, its, rtol)`` of every Newton step of one default run: the AMG matrix, the
    right-hand side, and the GMRES iterations and tolerance of the simulator's own solve
    (the full Newton operator, the AMG hierarchy possibly reused from an earlier step)."""
    systems = []
    original = solver.LinearSolver.__call__

    def keep(self, M, b, *, rtol, preconditioner=None):
        x, its = original(self, M, b, rtol=rtol, preconditioner=preconditioner)
        systems.append(((M if preconditioner is None else preconditioner).tocsr().copy(),
                        b.copy(), its, rtol))
        return x, its

    solver.LinearSolver.__call__ = keep
    try:
        res = melt_pool.simulate({"P": P, "v": v})
    finally:
        solver.LinearSolver.__call__ = original
    print(f"{P:g} W / {v:g} m/s: {res.status}, {len(systems)} Newton steps", flush=True)
    return systems


def _row(name: str, setup: float, solve: float, its: object, M: sp.csr_matrix,
         b: np.ndarray, x: np.ndarray) -> None:
    true = np.linalg.norm(b - M @ x) / np.linalg.norm(b)
    print(f"  {name:34s} setup {setup:7.3f}  solve {solve:7.3f}  its {its!s:>4}"
          f"  true rel. residual {true:.1e}", flush=True)


def compare(M: sp.csr_matrix, b: np.ndarray, rtol: float, lu: bool) -> None:
    for name, build in PRECONDITIONERS.items():
        t = time.process_time()
        pre = build(M)
        setup = time.process_time() - t
        res: list[float] = []
        t = time.process_time()
        x, _ = pyamg.krylov.gmres(M, b, tol=rtol, maxiter=200, M=pre, residuals=res)
        _row(name, setup, time.process_time() - t, len(res), M, b, x)
    if lu:
        t = time.process_time()
        fac = spla.splu(M.tocsc())
        setup = time.process_time() - t
        t = time.process_time()
        x = fac.solve(b)
        _row("SuperLU (direct)", setup, time.process_time() - t, "-", M, b, x)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", type=float, nargs=2, default=(152.0, 0.32),
                    metavar=("P", "V"))
    ap.add_argument("--steps", type=int, nargs="+", default=[40, 70, -12, -6])
    ap.add_argument("--rtol", type=float, default=1e-3)
    ap.add_argument("--no-lu", action="store_true", help="skip the direct solve")
    args = ap.parse_args()
    systems = capture(*args.case)
    for k in args.steps:
        M, b, its, rtol = systems[k]
        print(f"Newton step {k % len(systems)}: {M.shape[0]} cells; in the run {its} GMRES "
              f"iterations to {rtol:.1e}", flush=True)
        compare(M, b, args.rtol, lu=not args.no_lu)


if __name__ == "__main__":
    main()
