"""Newton iteration with pseudo-transient continuation and AMG-preconditioned GMRES.

Each step solves ``(V rho c_eff / dt - J) dT = R`` (physics.md: exact Jacobian through
Kirchhoff potentials, pseudo-transient continuation, each cell's temperature update
clipped to its own cap, at most ``max_update``). Where the linearisation is poor at a
few cells (cold powder beside and behind the pool, whose consolidated fraction and
hence conductivity follow the upstream field, can ask for 1e3-2e5 K), scaling the whole
update down to ``max_update`` let those cells set every other cell's step, and solves
near the keyhole threshold stalled for hundreds of iterations at a flat residual.
Clipped alone, such a cell can 2-cycle at its cap instead (a cell swinging between the
temperature floor and 400 K above it for 460 iterations at 96 W / 0.364 m/s): a cell
whose update was clipped and turns back halves its cap (down to ``CAP_MIN``), and a cell
moving on in the same direction doubles it (up to ``max_update``), a bisection on the
cells Newton cannot place. benchmarks/README.md, "What was tried for speed" and
"Known weaknesses", has the runs.

The pseudo time step follows switched evolution relaxation, ``dt_k =
dt_(k-1) clip(1.5 |R_(k-1)| / |R_k|, 2, 3)`` unless the residual rises by more than
``RISE`` (50 %), then ``dt_(k-1) / 4`` and at most 1.5x growth on the next step (so a
Newton 2-cycle shrinks dt until the pseudo-time term damps it), so the iteration turns
into plain Newton as the residual falls. Cells colder than ``T_S - COLD_MARGIN`` carry
no pseudo-time term: the laws are linear there (constant conductivity and heat capacity;
the radiative loss of the top cells is smooth), so Newton needs no damping, whereas a
pseudo-transient crawling down the long cold wake of the track would pace the iteration
after every cut of ``dt``. Smaller rises are let pass: a pseudo-transient carries heat
down the long tail of the pool, and the largest residual may grow while it does. After a
cut, dt stays below half the step that failed, a cap that doubles per successful step:
Newton can cycle at the kinks of the monotone and field consolidated fractions (a max
over the upstream line), and the cap tightens with every turn of such a cycle until the
pseudo-time term damps it; a slower regrowth would pace the last ten or twenty steps of
most solves (with the exposure form the converged state does not depend on it:
benchmarks/README.md, "The solver's path"). Cells crossing ``T_S`` or ``T_L`` stop just
past the kink. The consolidated fraction of the powder is ``frac(T)``
(:mod:`~.consolidation`) of the current iterate, with ``dR/dfrac dfrac/dT`` in the
Newton operator, so a converged state solves ``R(T, frac(T)) = 0`` whatever the path
(``consolidation="exposure"``, the default, and ``"field"``; for the exposure form the
coupling is applied matrix-free inside GMRES, :func:`_with_exposure`); or, with
``"monotone"``, the largest ``frac(T)`` of the solve's iterates: the front only
advances, at the price of a state that depends on the iteration path.

Two safeguards apply to the exposure form, whose converged state does not depend on
the path (:func:`_cycle_factor`, ``_stop_at_kinks(..., from_edge=True)``): a short
Newton cycle whose residual stays flat is not seen by the pseudo-time rule above (the
residual never rises by ``RISE``, so ``dt`` grows to ``DT_MAX``), and is broken by
halving the update at a 2-cycle of the whole field, and the update of each powder
cell that cycles with period 2-4 (a column at the beam's edge); and a cell that the kink
rule left 1 K outside the mushy zone stops at the kink again instead of jumping across
it. ``GUARD_MONOTONE`` applies both to the monotone form too; off, since they moved its
``G0`` by 2.5 % at 152 W / 0.32 m/s.

The absorptivity moves by at most ``A_STEP`` between Newton steps. Near the vapour
switch ``A(T_s)`` of consecutive iterates can differ by most of ``A_max - A_0``, and
Newton then wanders between the conduction and the keyhole branch (77 iterations in the
105 W stage at 152 W / 0.32 m/s, 33 with the limit, both with warm starts at 2e-5 s).
While the limit holds ``A`` back, ``A`` is not ``A(T_s)``, so its ``dA/dT`` term is left
out and the solve cannot converge: a converged state solves the unlimited equations.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pyamg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from calnet.simulators.melt_pool.assembly import Discretization
from calnet.simulators.melt_pool.consolidation import (
    Exposure,
    consolidated,
    exposure,
    fraction_coupling,
)
from calnet.simulators.melt_pool.properties import MaterialLaws

_DEBUG = bool(os.environ.get("CALNET_MELT_POOL_DEBUG"))
DT0 = 2e-6  # s, first pseudo time step
DT_MAX = 1.0
DT_MIN = 1e-9  # s
FRAC_TOL = 1e-4  # growth of the monotone consolidated fraction allowed at convergence
RISE = 1.5  # a residual rise by more than this factor cuts the pseudo time step
CEILING_GROWTH = 2.0  # per step, of the cap on dt (half the step that failed last)
LIN_FORCING = 0.1  # relative GMRES tolerance per unit of the scaled residual
LIN_CAP, LIN_FLOOR = 1e-3, 1e-10  # largest and smallest relative GMRES tolerance
CYCLE_STEP = 0.5  # update factor in a short Newton cycle (exposure form)
CYCLE_PERIODS = 4  # longest cycle period that _cycle_factor looks for
CYCLE_CELL = 0.1  # smallest update, relative to the largest, that a cell's cycle test sees
CYCLE_POWDER = True  # the cell cycle test sees only the cells of the powder layer
COLD_MARGIN = 300.0  # K: cells colder than T_S - COLD_MARGIN carry no pseudo-time term
GUARD_MONOTONE = False  # the exposure form's cycle test and kink rule for "monotone" too
CELL_CAPS = True  # per-cell caps on the update, halved on a turn (False: max_update for all)
CAP_MIN = 1.0  # K, smallest per-cell cap
STALL_ITS = 20  # iterations without a new lowest residual that switch on the stall mode
STALL_DT = 1e-4  # s, dt and its ceiling when the stall mode switches on
STALL_GROWTH = 1.2  # per calm step, growth of the ceiling on dt in the stall mode
ABANDON_ITS = 3  # iterations in a row past ``abandon`` that end a solve as "left branch"
A_STEP = 0.05  # largest change of the absorptivity between Newton steps (0: no limit)


@dataclass(frozen=True)
class SolveReport:
    """Outcome of :func:`newton_solve`."""

    T: np.ndarray  # (n_cells,) temperature (K)
    converged: bool
    reason: str
    iterations: int
    residual: float  # max |R| / (A P / 2)
    update: float  # last max |dT| (K)
    linear_iterations: int
    absorptivity: float
    surface_temperature: float
    frac: np.ndarray  # (n_cells,) consolidated fraction (1 in the substrate)


@dataclass(frozen=True)
class AbsorptivityLaw:
    """``A`` and ``dA/dT`` on the reconstruction stencil (None: lagged) from ``T``."""

    evaluate: Callable[[np.ndarray], tuple[float, np.ndarray | None, float]]


def _stop_at_kinks(T: np.ndarray, dT: np.ndarray, mat, *, from_edge: bool = False
                   ) -> np.ndarray:
    """``T + dT``, but a cell crossing ``T_S`` or ``T_L`` stops 1 K beyond it.

    The conductivity (up to 150x for powder) and ``c_eff`` change steeply across the
    mushy zone; letting a cell jump across it in one Newton step makes the iteration
    2-cycle. Cells land just past the kink and continue on the next step. With
    ``from_edge`` a cell sitting exactly 1 K outside a kink, where this rule puts cells
    that cross it downwards out of the mushy zone, stops at the kink too; without it
    such a cell crosses the whole mushy zone in one step, and Newton can 2-cycle between
    ``T_S - 1`` and ``T_L + 1`` (the exposure form at 235 W / 2.3 m/s). The monotone
    form keeps the rule without it.
    """
    new = T + dT
    edge = 1e-9 if from_edge else 0.0  # K, round-off margin on the landing points
    for kink in (mat.T_solidus, mat.T_liquidus):
        up = (T < kink - 1.0 + edge) & (new > kink + 1.0)
        down = (T > kink + 1.0 - edge) & (new < kink - 1.0)
        new = np.where(up, kink + 1.0, np.where(down, kink - 1.0, new))
    return new


class LinearSolver:
    """GMRES preconditioned by classical (Ruge-Stuben) AMG, the hierarchy reused.

    ``M`` is an M-matrix (upwind advection, Kirchhoff conduction); classical AMG handles
    its advection-dominated far field far better than smoothed aggregation (measured:
    10 vs 50 GMRES iterations and 0.2 vs 2 s setup at 73k cells). The AMG hierarchy of
    an earlier Newton matrix stays a good preconditioner while the iterates change
    little, so it is rebuilt only when GMRES needed more than ``REBUILD_ITS``
    iterations or after ``MAX_AGE`` reuses.

    The smoother is one forward Gauss-Seidel sweep before and one backward sweep after
    the coarse-grid correction (pyamg's default is a symmetric sweep on both sides,
    twice the smoothing work): the V-cycle stays symmetric in form, and the Krylov
    iteration counts barely change (measured: the same Newton path at 81 W / 1.5 m/s
    and 90 W / 2.3 m/s, 21-30 % less time per run).
    """

    REBUILD_ITS, MAX_AGE = 12, 4
    COARSE_SOLVER = "pinv"
    SMOOTHERS = {"presmoother": ("gauss_seidel", {"sweep": "forward"}),
                 "postsmoother": ("gauss_seidel", {"sweep": "backward"})}

    def __init__(self) -> None:
        self._ml = None
        self._age = 0
        self._last_its = 0

    @classmethod
    def hierarchy(cls, A: sp.csr_matrix, **overrides) -> pyamg.MultilevelSolver:
        """The AMG hierarchy this solver builds on ``A``; ``overrides`` replace its
        settings (``coarse_solver``, the smoothers, ``strength``; for benchmarks)."""
        settings = {"max_coarse": 400, "coarse_solver": cls.COARSE_SOLVER, **cls.SMOOTHERS}
        return pyamg.ruge_stuben_solver(A, **(settings | overrides))

    def __call__(self, M: sp.csr_matrix, b: np.ndarray, *, rtol: float,
                 preconditioner: sp.csr_matrix | None = None) -> tuple[np.ndarray, int]:
        """Solve ``M x = b``; the AMG hierarchy is built on ``preconditioner`` (an
        M-matrix close to ``M``; default ``M`` itself)."""
        Pm = M if preconditioner is None else preconditioner
        stale = (self._ml is None or self._last_its > self.REBUILD_ITS
                 or self._age >= self.MAX_AGE or self._ml.levels[0].A.shape != M.shape)
        x, its = self._solve(M, Pm, b, rtol, rebuild=stale)
        # GMRES stops on the preconditioned residual; check the true one
        if not stale and np.linalg.norm(b - M @ x) > 10 * rtol * np.linalg.norm(b):
            x, more = self._solve(M, Pm, b, rtol, rebuild=True)
            its += more
        self._last_its = its
        return x, its

    def _solve(self, M: sp.csr_matrix, Pm: sp.csr_matrix, b: np.ndarray, rtol: float, *,
               rebuild: bool) -> tuple[np.ndarray, int]:
        if rebuild:
            self._ml = self.hierarchy(Pm)
            self._age = 0
        self._age += 1
        res: list[float] = []
        x, _ = pyamg.krylov.gmres(M, b, tol=rtol, maxiter=80, M=self._ml.aspreconditioner(),
                                  residuals=res)
        return x, len(res)


def _cycle_factor(dT: np.ndarray, history: tuple[np.ndarray, ...],
                  eligible: np.ndarray | None = None) -> np.ndarray | float:
    """Factor on the Newton update ``dT``, scalar or per cell (n_cells,): ``CYCLE_STEP``
    in a short cycle, else 1.

    ``history`` holds the last updates, the latest first. The whole update is halved at
    a 2-cycle: it reverses the last update (cosine below -0.5) and repeats the one
    before (cosine above 0.5); halving lands on the cycle's midpoint. A single
    reversal is left alone: halving every update that reverses the last one slowed
    the pseudo-transients of the continuation stages enough that 152 W / 0.32 m/s ran
    out of ``max_iter``. A cell whose update mostly undoes the sum of its last
    ``p - 1`` updates and repeats its update ``p`` steps back (both within half its
    size; ``p`` 2 to ``CYCLE_PERIODS``) is halved alone, when its update is at least
    ``CYCLE_CELL`` of the largest and the cell is ``eligible`` ((n_cells,) bool; the
    powder layer in :func:`newton_solve`, ``CYCLE_POWDER``): the period-3 cycle of a
    beam-edge powder column at 209 W / 0.402 m/s. The same test on the whole field
    (cosines) halved pseudo-transient updates until 152 W / 0.32 m/s ran out of
    ``max_iter``. The cell test on every cell halved some 340 cells per step, a third
    of them in the substrate, while the fine solve at 131 W / 0.774 m/s crossed from
    the conduction to the keyhole branch, and that solve wandered until the run ran
    out of ``max_iter``; requiring also that the cell's update reverse its last one
    left a period-5 cycle at 236 W / 0.23 m/s unbroken.
    """
    if len(history) < 2:
        return 1.0
    norm = float(np.linalg.norm(dT))

    def cosine(a: np.ndarray) -> float:
        return float(dT @ a) / max(norm * float(np.linalg.norm(a)), 1e-300)

    if cosine(history[0]) < -0.5 and cosine(history[1]) > 0.5:
        return CYCLE_STEP
    size = np.abs(dT)
    cycling = np.zeros(dT.shape, dtype=bool)
    undone = np.zeros(dT.shape)
    for p in range(2, min(CYCLE_PERIODS, len(history)) + 1):
        undone = undone + history[p - 2]
        cycling |= ((np.abs(dT + undone) <= 0.5 * size)
                    & (np.abs(dT - history[p - 1]) <= 0.5 * size))
    cycling &= size >= CYCLE_CELL * size.max()
    if eligible is not None:
        cycling &= eligible
    return np.where(cycling, CYCLE_STEP, 1.0) if cycling.any() else 1.0


def _with_exposure(M: sp.csr_matrix, disc: Discretization, T: np.ndarray,
                   laws: MaterialLaws, cons: Exposure, dA: np.ndarray | None
                   ) -> sp.csr_matrix | spla.LinearOperator:
    """The Newton operator ``M - dR/dfrac (dfrac/dT + dfrac/dA dA/dT)``, matrix-free.

    ``M`` is the matrix at fixed ``frac``; ``dA`` the absorptivity gradient on the
    surface stencil ``disc.ts_cells`` (None when it is lagged). Returns ``M`` itself
    where no column's fraction depends on the field.
    """
    if not np.any(cons.dr):
        return M
    C = fraction_coupling(disc, T, cons.frac, laws)
    if C.nnz == 0:
        return M
    via_a = C @ cons.by_absorptivity() if dA is not None else None
    cells = disc.ts_cells

    def matvec(d: np.ndarray) -> np.ndarray:
        d = np.ravel(d)
        out = M @ d - C @ cons.apply(d)
        if via_a is not None:
            out -= via_a * float(dA @ d[cells])
        return out

    return spla.LinearOperator(M.shape, matvec=matvec, dtype=float)


def newton_solve(disc: Discretization, laws: MaterialLaws, T0: np.ndarray, *,
                 absorptivity: AbsorptivityLaw, k_powder: float, rtol: float, ttol: float,
                 max_iter: int, max_update: float, deadline: float | None,
                 dt0: float = DT0, consolidation: str = "exposure",
                 abandon: Callable[[float], bool] | None = None) -> SolveReport:
    """Drive the residual to ``max|R| <= rtol * A P / 2`` from the initial field ``T0``.

    ``consolidation="monotone"``: the consolidated fraction is the largest upstream-maximum
    ``frac(T)`` of the solve's iterates (it never decreases; convergence requires it to
    have stopped growing); ``"field"``: the upstream-maximum ``frac(T)`` of the current
    iterate, ``"exposure"``: the cumulative-exposure ``frac(T)`` of the current iterate,
    both with their coupling in the Newton operator (:mod:`~.consolidation`).

    A solve that goes ``STALL_ITS`` iterations without a new lowest scaled residual
    (a cycle of the update, the caps and ``dt`` near the keyhole threshold) enters a
    stall mode for the rest of the solve: every cell carries the pseudo-time term
    (also the cold ones), ``dt`` and its ceiling drop to ``STALL_DT`` and the ceiling
    regrows by ``STALL_GROWTH`` per calm step.

    ``abandon``, when given, is asked of every iterate's absorptivity whether the solve
    has left the branch it should stay on; after ``ABANDON_ITS`` yeses in a row the
    solve ends unconverged with the reason ``"left branch"``."""
    T = T0.copy()
    rho_c = None
    dt, r0_norm, upd, lin_total, calm = dt0, None, np.inf, 0, 10
    frac: np.ndarray | None = None
    reason, it, rnorm = "iteration limit reached", 0, np.inf
    A, Ts = np.nan, np.nan
    linear_solve = LinearSolver()
    ceiling = DT_MAX
    best, best_it, stalled = np.inf, 0, False
    guarded = consolidation == "exposure" or GUARD_MONOTONE
    history: tuple[np.ndarray, ...] = ()  # the last CYCLE_PERIODS updates, latest first
    damp = 1.0
    powder = disc.powder_cells.ravel()
    a_prev: float | None = None
    cap = np.full(T.shape, float(max_update))
    last: np.ndarray | None = None
    away = 0
    for it in range(1, max_iter + 1):
        if deadline is not None and time.monotonic() > deadline:
            reason = "time limit reached"
            break
        A, dA, Ts = absorptivity.evaluate(T)
        clipped = bool(A_STEP) and a_prev is not None and abs(A - a_prev) > A_STEP
        if clipped:  # relax towards A(T), lagged: no dA/dT for a value not on the law
            A, dA = a_prev + math.copysign(A_STEP, A - a_prev), None
        a_prev = A
        away = away + 1 if abandon is not None and abandon(A) else 0
        if ABANDON_ITS and away >= ABANDON_ITS:
            reason = "left branch"
            break
        cons = None
        if consolidation == "exposure":
            cons = exposure(disc, T, A, k_powder)
            target, dfrac = cons.frac, None
        else:
            target, dfrac = consolidated(disc, T, A, k_powder)
        if consolidation == "monotone":  # the front only advances within a solve; no coupling term
            grown = target if frac is None else np.maximum(frac, target)
            front_moved = frac is None or float(np.abs(grown - frac).max()) > FRAC_TOL
            frac, dfrac = grown, None
        else:
            frac, front_moved = target, False
        R, J = disc.evaluate(T, frac, laws, A, dA)
        rnorm = float(np.abs(R).max() / (A * disc.P / 2))
        if not np.isfinite(rnorm):
            reason = "non-finite residual"
            break
        if rnorm <= rtol and upd <= ttol and not front_moved and not clipped:
            return SolveReport(T, True, "", it - 1, rnorm, upd, lin_total, A, Ts, frac)
        r2 = float(np.linalg.norm(R))
        if rnorm < best - 1e-12:
            best, best_it = rnorm, it
        elif STALL_ITS and not stalled and it - best_it >= STALL_ITS:
            stalled = True
            dt, ceiling, calm = min(dt, STALL_DT), STALL_DT, 0
            if _DEBUG:
                print(f"stalled at it {it}: dt {dt:.1e}", flush=True)
        if r0_norm is not None:  # grow dt while the residual falls (SER-like)
            rising = r2 > RISE * r0_norm
            calm = 0 if rising else calm + 1
            if rising:  # the step just taken was too long: remember it
                ceiling = max(DT_MIN, 0.5 * dt)
            else:
                ceiling = min(DT_MAX, (STALL_GROWTH if stalled else CEILING_GROWTH) * ceiling)
            top = 3.0 if calm > 1 else 1.5  # slow regrowth after a rise: no 2-cycles
            grow = 0.25 if rising else float(np.clip(1.5 * r0_norm / r2, min(2.0, top), top))
            dt = float(np.clip(dt * grow, DT_MIN, ceiling))
        r0_norm = r2
        _, c = laws.enthalpy(T)
        rho_c = disc.density(frac) * c
        pseudo = np.where((T < disc.mat.T_solidus - COLD_MARGIN) & (not stalled), 0.0,
                          disc.volume * rho_c / dt)
        M = disc.system(J, pseudo, coupled=dA is not None)
        if cons is not None:
            full = _with_exposure(M, disc, T, laws, cons, dA)
        elif dfrac is not None and dfrac.nnz:
            full = M - fraction_coupling(disc, T, frac, laws) @ dfrac
        else:
            full = M
        dT, n_lin = linear_solve(full, R, rtol=min(LIN_CAP, max(LIN_FLOOR, LIN_FORCING * rnorm)),
                                 preconditioner=M)
        lin_total += n_lin
        big = float(np.abs(dT).max())
        if not np.isfinite(big):
            reason = "non-finite Newton update"
            break
        if CELL_CAPS and last is not None:  # a clipped cell that turns back: halve its cap
            turned = (dT * last < 0) & (np.abs(dT) > cap)
            cap = np.where(turned, np.maximum(0.5 * cap, CAP_MIN),
                           np.where(dT * last > 0, np.minimum(2.0 * cap, max_update), cap))
        dT = np.clip(dT, -cap, cap)
        if guarded:
            damp = _cycle_factor(dT, history, powder if CYCLE_POWDER else None)
            dT *= damp
            history = (dT, *history[:CYCLE_PERIODS - 1])
        last = dT
        T = np.maximum(_stop_at_kinks(T, dT, disc.mat, from_edge=guarded),
                       0.5 * disc.mat.T_ambient)
        upd = min(big, max_update)
        if _DEBUG:
            print(f"it {it} r {rnorm:.3e} dt {dt:.2e} dT {big:.1f} lin {n_lin} A {A:.3f} "
                  f"Ts {Ts:.0f} Tmax {T.max():.0f} front moved {front_moved} "
                  f"at {np.unravel_index(np.argmax(np.abs(dT)), disc.mesh.shape)} "
                  f"T {T[np.argmax(np.abs(dT))]:.0f} factor {np.min(damp)} "
                  f"on {np.sum(np.asarray(damp) < 1.0)}", flush=True)
    return SolveReport(T, False, reason, it, rnorm, upd, lin_total, A, Ts, frac)
