"""NUTS sampling of a calibration log-density: several chains, compiled once, reused.

The sampler is BlackJAX's NUTS kernel after Stan's windowed warm-up (BlackJAX's dual
averaging of the step size and Welford estimate of a diagonal or dense inverse mass
matrix, on Stan's window schedule), the whole warm-up + sampling run of a chain being one
XLA program with one copy of the kernel. The same program checks the initial points: a
chain whose log-density or gradient is not finite there does not run, and
:func:`sample_nuts` raises. Chains run in parallel across XLA host devices (``pmap``)
when there are at least two devices (see :func:`calnet.calibration.devices.configure_host_devices`),
otherwise one after another inside one program (``sequential``) or in lock-step
(``vectorized``).

The compiled program takes the log-density's data as an *argument*: it is cached under
the log-density's hashable ``spec``, the sampler settings and the data shapes, so that a
second calibration with new data of the same shapes (leave-one-out folds, repeated runs)
does not recompile (a program traced again per fold would cost its compile time each time).

Any object with a hashable ``spec`` (pure ``spec.logdensity(data, u)`` and
``spec.constrain(data, u)``), ``data``, ``dim``, ``name``, ``init(seed, n_chains)``,
``sampled_vars``, ``dims`` and ``coords`` can be sampled; the network's KOH model
(:class:`calnet.calibration.koh.KOHDensity`, built by
:func:`calnet.calibration.calibrate_network.build_koh`) is the one calnet uses.
"""

from __future__ import annotations

import sys
import threading
import time
import warnings
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager, nullcontext, suppress
from dataclasses import dataclass
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from blackjax.adaptation.mass_matrix import mass_matrix_adaptation
from blackjax.adaptation.step_size import dual_averaging_adaptation
from blackjax.adaptation.window_adaptation import build_schedule
from blackjax.mcmc import nuts

from calnet._jax import FEW_CALLS, device_array
from calnet.calibration.diagnostics import import_arviz, stuck_chains, unvisited_mode
from calnet.calibration.koh import initial_point_message
from calnet.errors import CalibrationError, CalibrationWarning
from calnet.interrupts import end_now, may_end_now, program_running
from calnet.parallel import one_blas_thread
from calnet.progress import Lines

__all__ = ["sample_nuts", "clear_cache", "cache_info", "CHAIN_METHODS"]

CHAIN_METHODS = ("auto", "parallel", "sequential", "vectorized")
_CACHE_SIZE = 16
#: prior draws per chain among which its initial point is the one of highest log-density
INIT_CANDIDATES = 64


@dataclass(frozen=True)
class _Config:
    """Everything that shapes the compiled program except the data shapes."""

    spec: Hashable
    dim: int
    num_warmup: int
    num_draws: int
    thin: int
    target_accept: float
    max_tree_depth: int
    dense_mass: bool
    chain_method: str
    groups: int  # number of devices the chains are spread over (parallel)
    progress_every: int  # 0: no progress callbacks compiled in


# ----------------------------------------------------------------------------- progress
_PROGRESS: dict[str, Any] = {"fn": None}
_PROGRESS_LOCK = threading.Lock()


def _emit(chain, iteration, total):
    fn = _PROGRESS["fn"]
    if fn is not None:
        with _PROGRESS_LOCK:
            fn(int(chain), int(iteration), int(total))


class _TextProgress:
    """A one-line progress bar on stderr, redrawn in place (a terminal only)."""

    def __init__(self, name: str, num_chains: int, total: int):
        self.name, self.total = name, total
        self.done = [0] * num_chains
        self.t0 = time.perf_counter()

    def __call__(self, chain: int, iteration: int, total: int) -> None:
        self.done[chain] = iteration
        frac = sum(self.done) / (self.total * len(self.done))
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.name}: [{bar:<30}] {100 * frac:5.1f}% "
                         f"{time.perf_counter() - self.t0:6.1f}s")
        if frac >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()


class _ChainLines:
    """Progress of all chains as plain :class:`~calnet.progress.Lines`: a line at every
    10 % of the iterations (warm-up included), and ``warm-up`` lines while the warm-up,
    which reports no iterations, runs."""

    def __init__(self, lines: Lines, num_chains: int, num_warmup: int, total: int):
        self.lines, self.total = lines, total
        self.done = [0] * num_chains
        self.warmup = f"warm-up, {num_warmup} iterations x {num_chains} chains"

    def __call__(self, chain: int, iteration: int, total: int) -> None:
        self.done[chain] = iteration
        frac = sum(self.done) / (self.total * len(self.done))
        self.lines.update(frac, f"{100 * frac:.0f} % of the iterations")

    def status(self) -> str:
        if not any(self.done):
            return self.warmup
        return f"{100 * sum(self.done) / (self.total * len(self.done)):.0f} % of the iterations"


@contextmanager
def _timed_lines(lines: Lines, what: str, t_compile: float) -> Iterator[None]:
    """Lines without iteration counts: the start, one every 10 s, the end."""
    lines.restart()
    lines.note((f"compiled in {t_compile:.1f} s; " if t_compile else "") + what)
    with lines.heartbeat(lambda: "sampling"):
        yield
    lines.note("sampled")


def _counts_iterations(progress) -> bool:
    """Whether ``progress`` needs iteration callbacks compiled into the sampler. A program
    with host callbacks is not kept in JAX's on-disk compilation cache, so
    :class:`~calnet.progress.Lines` (what ``calnet run`` passes) go without them."""
    return bool(progress) and not isinstance(progress, Lines)


def _reporter(progress, name: str, num_chains: int, num_warmup: int, num_draws: int,
              t_compile: float):
    """``(fn(chain, iteration, total) or None, context to run the chains in)``."""
    total = num_warmup + num_draws
    if not progress:
        return None, nullcontext()
    if isinstance(progress, Lines):
        return None, _timed_lines(progress, f"sampling {num_chains} chains x ({num_warmup} "
                                  f"warm-up + {num_draws}) iterations", t_compile)
    if callable(progress):
        return progress, nullcontext()
    if sys.stderr.isatty():
        return _TextProgress(name, num_chains, total), nullcontext()
    lines = Lines(name)
    fn = _ChainLines(lines, num_chains, num_warmup, total)
    lines.note((f"compiled in {t_compile:.1f} s; " if t_compile else "") + fn.warmup)
    return fn, lines.heartbeat(fn.status)


def _maybe_report(cfg: _Config, chain, i, total):
    if cfg.progress_every:
        jax.lax.cond((i + 1) % cfg.progress_every == 0,
                     lambda: jax.debug.callback(_emit, chain, i + 1, total),
                     lambda: None)


# ----------------------------------------------------------------------------- warm-up
class _Adaptation(NamedTuple):
    """Stan's windowed adaptation: dual averaging of the step size, a Welford estimate of
    the inverse mass matrix over slow windows that forget each other."""

    step: Any  # dual-averaging state
    metric: Any  # mass-matrix estimation state
    step_size: jax.Array
    inverse_mass_matrix: jax.Array


def _adaptation(cfg: _Config):
    """``(init, update, final)`` of :class:`_Adaptation`, from BlackJAX's dual averaging
    and mass-matrix estimation (the pieces of its ``window_adaptation``, whose ``run``
    owns its own copy of the NUTS kernel)."""
    da_init, da_update, da_final = dual_averaging_adaptation(cfg.target_accept)
    mm_init, mm_update, mm_final = mass_matrix_adaptation(not cfg.dense_mass)

    def init(step_size):
        metric = mm_init(cfg.dim)
        return _Adaptation(da_init(step_size), metric, jnp.asarray(step_size, dtype=float),
                           metric.inverse_mass_matrix)

    def update(a: _Adaptation, slow, window_end, position, acceptance_rate):
        step = da_update(a.step, acceptance_rate)
        metric = jax.lax.cond(slow, lambda m: mm_update(m, position), lambda m: m, a.metric)
        a = _Adaptation(step, metric, jnp.exp(step.log_step_size), a.inverse_mass_matrix)

        def close_window(a):  # a new mass matrix; the step size starts again from it
            metric = mm_final(a.metric)
            step = da_init(da_final(a.step))
            return _Adaptation(step, metric, jnp.exp(step.log_step_size),
                               metric.inverse_mass_matrix)
        return jax.lax.cond(window_end, close_window, lambda a: a, a)

    def final(a: _Adaptation):
        return jnp.exp(a.step.log_step_size_avg), a.inverse_mass_matrix

    return init, update, final


def _schedule(num_warmup: int, num_draws: int) -> tuple[np.ndarray, ...]:
    """Per iteration: warm-up?, slow window?, end of a slow window? (Stan's schedule)."""
    with jax.ensure_compile_time_eval():  # BlackJAX builds it with jnp; a constant here
        plan = np.asarray(build_schedule(num_warmup), dtype=int).reshape(-1, 2)
    pad = np.zeros(num_draws, dtype=int)
    warm = np.r_[np.ones(num_warmup, dtype=bool), pad.astype(bool)]
    return warm, np.r_[plan[:, 0], pad].astype(bool), np.r_[plan[:, 1], pad].astype(bool)


# ----------------------------------------------------------------------------- one chain
def _run_chain(cfg: _Config, data, key, u0, chain):
    """Warm-up then sampling of one chain, as one XLA program with one NUTS kernel.

    The warm-up iterations and the sampling iterations are one scan: the kernel runs with
    the adapted step size and mass matrix during the warm-up and with their final values
    after it, so that it is traced and compiled once. A chain whose initial point has a
    non-finite log-density or gradient does not run (its outputs are zeros).

    Returns the positions and transition statistics of the sampling iterations, the
    final step size and inverse mass matrix, and the log-density and whether it and its
    gradient are finite at the initial point.
    """
    logdensity = partial(cfg.spec.logdensity, data)
    key_w, key_s = jax.random.split(key)
    kernel = nuts.build_kernel()
    init, update, final = _adaptation(cfg)
    state0 = nuts.init(u0, logdensity)
    ok = jnp.isfinite(state0.logdensity) & jnp.all(jnp.isfinite(state0.logdensity_grad))
    total = cfg.num_warmup + cfg.num_draws
    warm, slow, window_end = (jnp.asarray(a) for a in _schedule(cfg.num_warmup,
                                                                 cfg.num_draws))
    keys = jnp.concatenate([jax.random.split(key_w, cfg.num_warmup),
                            jax.random.split(key_s, cfg.num_draws)])

    def one_step(carry, xs):
        state, adapt, step_size, imm = carry
        k, i, w, s, e = xs
        step_size = jnp.where(w, adapt.step_size, step_size)
        imm = jnp.where(w, adapt.inverse_mass_matrix, imm)
        state, info = kernel(k, state, logdensity, step_size, imm,
                             max_num_doublings=cfg.max_tree_depth)
        adapted = update(adapt, s, e, state.position, info.acceptance_rate)
        adapt = jax.tree.map(lambda a, b: jnp.where(w, a, b), adapted, adapt)
        # after the last warm-up iteration the step size and mass matrix are frozen
        done = final(adapt)
        last = i == cfg.num_warmup - 1
        step_size, imm = (jnp.where(last, d, p) for d, p in zip(done, (step_size, imm),
                                                                strict=True))
        _maybe_report(cfg, chain, i, total)
        return (state, adapt, step_size, imm), (state.position, _stats(state, info))

    adapt = init(1.0)
    carry = (state0, adapt, adapt.step_size, adapt.inverse_mass_matrix)
    xs = (keys, jnp.arange(total), warm, slow, window_end)

    def run(carry):
        (_, _, step_size, imm), (positions, stats) = jax.lax.scan(one_step, carry, xs)
        return (jax.tree.map(lambda a: a[cfg.num_warmup:], positions),
                jax.tree.map(lambda a: a[cfg.num_warmup:], stats), step_size, imm)

    shapes = jax.eval_shape(run, carry)
    out = jax.lax.cond(ok, run, lambda c: jax.tree.map(
        lambda sd: jnp.zeros(sd.shape, sd.dtype), shapes), carry)
    return (*out, state0.logdensity, ok)


def _finished(pending, name: str, progress):
    """``pending`` (the chains' outputs, computing) once computed. Ctrl-C cannot stop a
    running XLA program: after one, this says so, waits for the program to end (a
    process that ends with the program still running can crash in its clean-up) and
    raises KeyboardInterrupt then. Under ``calnet run`` SIGTERM does not wait: the
    process ends at once (:func:`calnet.interrupts.program_running`)."""
    with program_running():
        return _wait(pending, name, progress)


def _wait(pending, name: str, progress):
    try:
        return jax.block_until_ready(pending)
    except KeyboardInterrupt:
        text = ("stopping once the chains in flight end (a running program cannot be "
                "interrupted; " + ("Ctrl-C again" if may_end_now() else "Ctrl-\\")
                + " ends the process at once)")
        said = False
        if isinstance(progress, Lines):  # they say the stage's name
            with suppress(KeyboardInterrupt):  # calnet run's lines stop at Ctrl-C
                progress.note(text)
                said = True
        if not said:
            try:
                print(f"{name}: {text}", file=sys.stderr, flush=True)
            except KeyboardInterrupt:  # a second Ctrl-C while the line is written
                end_now(130, "Ctrl-C again while the chains ran")
        while True:
            try:
                jax.block_until_ready(pending)
                break
            except KeyboardInterrupt:  # a second Ctrl-C: a command ends at once,
                end_now(130, "Ctrl-C again while the chains ran")
                continue  # library code still waits for the same program
        raise


def _chains(index: list[int], n: int) -> str:
    """``[1]`` -> ``"chain 2 of 4"``, ``[0, 2]`` -> ``"chains 1 and 3 of 4"`` (1-based)."""
    one = [str(i + 1) for i in index]
    names = one[0] if len(one) == 1 else ", ".join(one[:-1]) + " and " + one[-1]
    return f"chain{'s' if len(one) > 1 else ''} {names} of {n}"


def _stats(state, info) -> dict:
    return {"diverging": info.is_divergent, "energy": info.energy,
            "n_steps": info.num_integration_steps,
            "tree_depth": info.num_trajectory_expansions,
            "acceptance_rate": info.acceptance_rate, "lp": state.logdensity}


def _build(cfg: _Config) -> Callable:
    """The (not yet compiled) program ``(keys, u0, chain_ids, data) -> outputs``."""
    one = partial(_run_chain, cfg)

    def seq(keys, u0, ids, data):
        return jax.lax.map(lambda a: one(data, *a), (keys, u0, ids))

    if cfg.chain_method == "parallel":
        def per_device(keys, u0, ids, data):  # (chains_per_device, ...)
            return seq(keys, u0, ids, data)
        return jax.pmap(per_device, in_axes=(0, 0, 0, None))
    if cfg.chain_method == "vectorized":
        return jax.jit(jax.vmap(lambda k, u, i, d: one(d, k, u, i), in_axes=(0, 0, 0, None)))
    return jax.jit(seq)


_COMPILED: OrderedDict = OrderedDict()
_STATS = {"hits": 0, "misses": 0}


def clear_cache() -> None:
    """Forget all compiled samplers."""
    _COMPILED.clear()
    _STATS.update(hits=0, misses=0)


def cache_info() -> dict[str, int]:
    """``dict(hits, misses, size)`` of the compiled-sampler cache."""
    return {**_STATS, "size": len(_COMPILED)}


def _shape_key(tree) -> tuple:
    leaves, treedef = jax.tree.flatten(tree)
    return (treedef, tuple((jnp.shape(x), jnp.result_type(x).name) for x in leaves))


def _compiled(cfg: _Config, args) -> tuple[Any, float]:
    key = (cfg, _shape_key(args))
    if key in _COMPILED:
        _COMPILED.move_to_end(key)
        _STATS["hits"] += 1
        return _COMPILED[key], 0.0
    _STATS["misses"] += 1
    t0 = time.perf_counter()
    exe = _build(cfg).lower(*args).compile()
    seconds = time.perf_counter() - t0
    _COMPILED[key] = exe
    while len(_COMPILED) > _CACHE_SIZE:
        _COMPILED.popitem(last=False)
    return exe, seconds


def _resolve_method(chain_method: str, num_chains: int) -> tuple[str, int]:
    if chain_method not in CHAIN_METHODS:
        raise CalibrationError(f"chain_method must be one of {CHAIN_METHODS}, "
                               f"got {chain_method!r}")
    n_dev = jax.local_device_count()
    groups = max(g for g in range(1, min(n_dev, num_chains) + 1) if num_chains % g == 0)
    if chain_method == "auto":
        chain_method = "parallel" if groups > 1 else "sequential"
    if chain_method == "parallel" and groups == 1:
        chain_method = "sequential"  # one device: nothing to spread over
    return chain_method, groups


def _logdensity_fn(spec):
    # evaluated once per calibration: compiled quickly rather than optimised
    return jax.jit(jax.vmap(spec.logdensity, in_axes=(None, 0)), compiler_options=FEW_CALLS)


_LOGDENSITY: OrderedDict = OrderedDict()


def _per_spec(cache: OrderedDict, spec, build: Callable):
    """``cache[spec]``, built by ``build(spec)`` on first use; at most ``_CACHE_SIZE``
    entries, the oldest dropped."""
    if spec not in cache:
        cache[spec] = build(spec)
        while len(cache) > _CACHE_SIZE:
            cache.popitem(last=False)
    return cache[spec]


def best_starts(ld, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per chain, the row of ``candidates`` (chains, K, dim) of highest finite log-density
    (the first where none is finite, so that the sampler's check names that chain), and
    every candidate's log-density (chains, K)."""
    logdensity = _per_spec(_LOGDENSITY, ld.spec, _logdensity_fn)
    chains, k, dim = candidates.shape
    lps = np.asarray(logdensity(ld.data, device_array(candidates.reshape(-1, dim),
                                                      float))).reshape(chains, k)
    best = np.argmax(np.where(np.isfinite(lps), lps, -np.inf), axis=1)
    return candidates[np.arange(chains), best], lps


def _constrain_fn(spec):
    return jax.jit(jax.vmap(jax.vmap(spec.constrain, in_axes=(None, 0)), in_axes=(None, 0)),
                   compiler_options=FEW_CALLS)


_CONSTRAIN: OrderedDict = OrderedDict()


def _constrain_draws(ld, positions) -> dict[str, np.ndarray]:
    """Constrained draws (chain, draw, ...) from unconstrained positions (chain, draw, dim)."""
    constrain = _per_spec(_CONSTRAIN, ld.spec, _constrain_fn)
    return jax.tree.map(np.asarray, constrain(ld.data, device_array(positions, float)))


def _where(ld, positions, chains) -> dict[int, str]:
    """``{chain: "a = 1.2, b = 3.4"}``: the mean of each parameter's draws in the given
    chains of ``positions`` (chain, draw, dim), for a message."""
    draws = _constrain_draws(ld, positions[np.asarray(chains)])
    # the calibration parameters where the density has them, else every sampled variable
    shown = [v for v, _ in getattr(ld.spec, "groups", ())] or list(ld.sampled_vars)
    out = {}
    for k, c in enumerate(chains):
        parts = [f"{name} = {float(np.mean(draws[var][k][..., j])):.4g}"
                 for var in shown for j, name in enumerate(ld.coords[ld.dims[var][0]])]
        out[c] = ", ".join(parts)
    return out


def _check_settings(num_chains, num_warmup, num_draws, thin, target_accept, max_tree_depth):
    if num_chains < 1 or num_warmup < 0 or num_draws < 1 or thin < 1:
        raise CalibrationError(
            f"expected num_chains >= 1, num_warmup >= 0, num_draws >= 1 and thin >= 1, got "
            f"{num_chains}, {num_warmup}, {num_draws}, {thin}")
    if num_draws // thin < 1:
        raise CalibrationError(f"thin={thin} keeps no draw out of num_draws={num_draws}")
    if not 0.0 < target_accept < 1.0 or not 1 <= max_tree_depth <= 20:
        raise CalibrationError(f"expected 0 < target_accept < 1 and 1 <= max_tree_depth <= 20, "
                               f"got {target_accept}, {max_tree_depth}")


def sample_nuts(
    ld,
    *,
    seed: int = 0,
    num_chains: int = 4,
    num_warmup: int = 1000,
    num_draws: int = 1000,
    thin: int = 1,
    init=None,
    target_accept: float = 0.8,
    max_tree_depth: int = 10,
    dense_mass: bool = False,
    chain_method: str = "auto",
    progress: bool | Callable[[int, int, int], None] = False,
    compiled: Callable[[], None] | None = None,
    warn: bool = True,
):
    """Sample a calibration log-density with NUTS; return an ArviZ ``InferenceData``.

    Parameters
    ----------
    ld : KOHLogDensity (or an object with the same protocol, see :mod:`.koh`)
    seed : int
        Seed of the initial points and of the chains; the same seed gives identical draws.
    num_chains, num_warmup, num_draws : int
        Chains (default 4), warm-up iterations per chain (discarded), iterations after it.
    thin : int
        Keep every ``thin``-th iteration: ``num_draws // thin`` draws per chain.
    init : array (num_chains, dim), optional
        Initial points on the unconstrained scale. Default: for each chain the one of
        highest log-density among ``INIT_CANDIDATES`` (64) draws from the priors, so that
        a narrow mode of the posterior (a sharp feature of a model, precise data) is
        found by at least one chain; chains stuck in a far lower mode are then restarted
        from the others (below).
    target_accept : float
        Target acceptance rate of the step-size adaptation.
    max_tree_depth : int
        Maximum number of trajectory doublings.
    dense_mass : bool
        Adapt a dense inverse mass matrix instead of a diagonal one.
    chain_method : {"auto", "parallel", "sequential", "vectorized"}
        ``auto``: ``parallel`` (pmap over XLA host devices) when at least two devices can
        share the chains, else ``sequential``. BLAS is held to one thread while the
        chains run (see :func:`calnet.parallel.one_blas_thread`).
    progress : bool, Lines or callable
        ``True``: a bar on stderr when it is a terminal, else plain lines (a line at
        every 10 % of the iterations, and one every 10 s during the warm-up);
        ``fn(chain, iteration, total)``, called during the sampling iterations. Both
        compile callbacks into the sampler, which JAX then keeps out of its on-disk
        cache. A :class:`~calnet.progress.Lines` gets lines without iteration counts
        (the start, one every 10 s, the end) from the program that ``False`` runs.
    compiled : callable, optional
        Called with no argument once the program is compiled (or found in the cache),
        just before the chains run.
    warn : bool, default True
        Warn of chains stuck in a local mode (run again); without it the message goes
        to the attribute ``stuck_note`` instead (for calibrations in a thread, whose
        warnings would mix with another's).

    Returns
    -------
    arviz.InferenceData
        ``posterior``: ``theta`` (chain, draw, theta_dim) with the parameter names as
        coordinates, ``ell`` (chain, draw, ell_dim), ``sd2``, ``se2`` (chain, draw) (fixed
        hyperparameters left out); ``sample_stats``: ``diverging``, ``energy``, ``n_steps``,
        ``tree_depth``, ``acceptance_rate``, ``lp``, ``step_size``; ``observed_data``:
        ``y``; attrs: model, sampler settings, ``compile_time`` and ``sampling_time`` (s).

    Raises
    ------
    CalibrationError
        Bad settings, or a non-finite log-density or gradient at the initial points.
    """
    az = import_arviz()

    _check_settings(num_chains, num_warmup, num_draws, thin, target_accept, max_tree_depth)
    method, groups = _resolve_method(chain_method, num_chains)
    total = num_warmup + num_draws
    every = max(1, total // 50) if _counts_iterations(progress) else 0
    cfg = _Config(ld.spec, ld.dim, num_warmup, num_draws, thin, float(target_accept),
                  max_tree_depth, bool(dense_mass), method, groups, every)
    screening = None
    if init is None:  # screened beside the sampler's compilation, which needs shapes only
        candidates = np.asarray(ld.init(seed, num_chains * INIT_CANDIDATES),
                                dtype=float).reshape(num_chains, -1, ld.dim)
        pool = ThreadPoolExecutor(max_workers=1)
        screening = pool.submit(best_starts, ld, candidates)
        pool.shutdown(wait=False)
        u0 = candidates[:, 0]
    else:
        u0 = np.asarray(init, dtype=float)
        if u0.shape != (num_chains, ld.dim):
            raise CalibrationError(f"{ld.name}: init must have shape ({num_chains}, "
                                   f"{ld.dim}), got {u0.shape}")
    ids = np.arange(num_chains)

    def host(a):  # host arrays: pmap places each device's share itself (a JAX array would
        # be cut by a compiled slicing program), and reshaping them compiles nothing
        if method != "parallel":
            return a
        return a.reshape((groups, num_chains // groups) + a.shape[1:])

    def chain_keys(stream: int):
        return np.asarray(jax.random.split(
            jax.random.fold_in(jax.random.PRNGKey(seed), stream), num_chains))

    args = (host(chain_keys(1)), host(u0), host(ids), ld.data)
    exe, t_compile = _compiled(cfg, args)
    if screening is not None:
        u0, candidate_lp = screening.result()
        args = (args[0], host(u0), *args[2:])
    if compiled is not None:
        compiled()

    def run(args, again: bool = False):
        # the second pass (stuck chains) reuses the compiled program: no compile to report
        _PROGRESS["fn"], running = _reporter(progress, ld.name, num_chains, num_warmup,
                                             num_draws, 0.0 if again else t_compile)
        try:
            with running, one_blas_thread():  # XLA's LAPACK calls go to OpenBLAS
                out = _finished(exe(*args), ld.name, progress)
        finally:
            _PROGRESS["fn"] = None
        if method == "parallel":  # back to (chains, ...)
            out = jax.tree.map(lambda a: np.asarray(a).reshape((num_chains,) + a.shape[2:]),
                               out)
        return jax.tree.map(np.asarray, out)

    t0 = time.perf_counter()
    positions, stats, step_size, _, lp0, ok = run(args)
    if not ok.all():
        raise CalibrationError(initial_point_message(ld.name, lp0, ~ok))
    stuck = stuck_chains(stats["lp"])
    if stuck:
        # a chain stuck in a far lower mode would misstate the posterior
        # (diagnostics.stuck_chains): every chain runs again, warm-up included, the stuck
        # ones from the other chains' last draws, so that the posterior keeps its chains
        kept = np.setdiff1d(np.arange(num_chains), stuck)
        mean_lp = stats["lp"].mean(axis=1)
        gap = mean_lp[kept].max() - mean_lp[stuck]
        best = int(kept[np.argmax(mean_lp[kept])])
        where = _where(ld, positions, [*stuck, best])
        restart = positions[:, -1].copy()
        restart[stuck] = positions[kept[np.arange(len(stuck)) % len(kept)], -1]
        positions, stats, step_size, _, lp0, ok = run(
            (host(chain_keys(2)), host(restart), host(ids), ld.data), again=True)
        still = stuck_chains(stats["lp"]) if ok.all() else list(range(num_chains))
        at = "; ".join(f"chain {c + 1} at {where[c]}" for c in stuck)
        stuck_note = (
            f"{ld.name}: {_chains(stuck, num_chains)} stuck in a local mode of the "
            f"posterior (mean log density {', '.join(f'{g:.0f}' for g in gap)} below the "
            f"best chain's; {at}, against {where[best]} for chain {best + 1}); every chain "
            "ran again, the stuck ones from the others' last draws"
            + (f", and {_chains(still, num_chains)} stuck again" if still else "")
            + (". That mode holds" if len(stuck) == 1 else ". Those modes hold")
            + " a negligible share of the posterior, but each is a far worse fit of the "
            "data: the model or its surrogate may be poor there (with the surrogate's "
            "variance in the likelihood, a worse fit costs less where the surrogate is "
            "uncertain, often at the edges of the campaign's box: more runs there may "
            "remove such a mode)")
        if warn:
            warnings.warn(stuck_note, CalibrationWarning, stacklevel=2)
        if not ok.all():
            raise CalibrationError(initial_point_message(ld.name, lp0, ~ok))
    unvisited = ""
    if screening is not None and ok.all():
        c = unvisited_mode(positions, stats["lp"], candidates.reshape(-1, ld.dim),
                           candidate_lp.ravel())
        if c is not None:
            point = candidates.reshape(-1, ld.dim)[c]
            at = _where(ld, np.broadcast_to(point, (1, 1, ld.dim)), [0])[0]
            unvisited = (
                f"{ld.name}: a prior draw at {at} has a log density as high as the "
                "chains' draws but lies far from every chain: the posterior has a mode "
                "the chains did not visit, and the chains' share of each mode is set by "
                "where they started, not by the modes' mass; compare runs with other "
                "seeds, and add data or bounds that tell the modes apart")
            if warn:
                warnings.warn(unvisited, CalibrationWarning, stacklevel=2)
    t_sample = time.perf_counter() - t0
    keep = slice(thin - 1, None, thin)  # the program returns the sampling iterations only
    constrained = _constrain_draws(ld, positions[:, keep])
    posterior = {v: constrained[v] for v in ld.sampled_vars}
    n_kept = num_draws // thin
    # a kept draw is divergent if any transition since the previous kept draw was
    div = stats["diverging"][:, :n_kept * thin]
    stats = {k: v[:, keep] for k, v in stats.items()}
    stats["diverging"] = div.reshape(num_chains, n_kept, thin).any(axis=2)
    stats["step_size"] = np.repeat(step_size[:, None], n_kept, axis=1)
    attrs = {"model": ld.name, "inference_library": "calnet (BlackJAX NUTS)",
             "seed": seed, "num_warmup": num_warmup, "num_draws": num_draws, "thin": thin,
             "target_accept": target_accept, "max_tree_depth": max_tree_depth,
             "dense_mass": int(dense_mass), "chain_method": method,
             "chains_restarted": ",".join(map(str, stuck)),
             "stuck_note": "" if warn or not stuck else stuck_note,
             "unvisited_note": "" if warn else unvisited,
             "compile_time": t_compile, "sampling_time": t_sample}
    idata = az.from_dict(posterior=posterior, sample_stats=stats,
                         observed_data={"y": np.asarray(ld.data["y"])},
                         coords=ld.coords, dims={**ld.dims, "y": ["obs"]})
    for group in ("posterior", "sample_stats"):
        idata[group].attrs.update(attrs)
    return idata

