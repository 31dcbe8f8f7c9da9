"""Kennedy-O'Hagan log-density of one model, discrepancy integrated out.

method.md section 3 (KOH 2001 with scale factor rho = 1):

    y = yhat(X; theta) + delta(X) + eps,   delta ~ GP(0, C_delta),  eps ~ N(0, se2 I)
    C_delta(x_i, x_j) = sd2 * exp(-0.5 * sum_d (x_id - x_jd)^2 / ell_d^2)

so that ``y ~ MVN(yhat(X; theta), C_delta(X, X) + se2 I [+ diag(emulator variance)])``.

The log-density is split in two parts so that a compiled sampler can be reused across
calibrations of the same shapes (leave-one-out, several data sets; koh_anchor pitfall 4):

* :class:`KOHSpec`, a hashable frozen description (the mean function, the priors, which
  hyperparameters are fixed, names) whose methods ``logdensity(data, u)`` and
  ``constrain(data, u)`` are pure JAX functions;
* ``data``, a pytree of arrays (observations, the pairwise squared differences of the
  discrepancy inputs, the mean function's arguments, the fixed hyperparameter values).

:class:`KOHLogDensity` binds the two. Any object with ``spec`` (hashable, with those two
methods), ``data``, ``dim``, ``name``, ``init``, ``sampled_vars``, ``dims`` and ``coords``
can be sampled by :func:`calnet.calibration.sampling.sample_nuts`; the network-level
(segmented/joint) log-densities follow the same protocol.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import jax.scipy.linalg as jsl  # noqa: E402
import numpy as np  # noqa: E402

from calnet.calibration.priors import (  # noqa: E402
    InverseGamma,
    LogNormal,
    Prior,
    init_from_priors,
    stack_priors,
)
from calnet.errors import CalibrationError, CalibrationWarning  # noqa: E402

__all__ = ["KOHSpec", "KOHLogDensity", "build_logdensity", "check_initial", "HYPERPARAMETERS"]

HYPERPARAMETERS = ("ell", "sd2", "se2")
_LOG_2PI = math.log(2.0 * math.pi)
#: reference priors (method.md section 3), unit-cube inputs and standardised outputs
DEFAULT_ELL_PRIOR = LogNormal(0.0, 0.5)
DEFAULT_VARIANCE_PRIOR = InverseGamma(2.0, 1.0)


@jax.custom_vjp
def mvn_logpdf_chol(r, K):
    """``log N(r; 0, K)`` through the Cholesky factor of ``K``: (n,), (n, n) -> scalar.

    The reverse-mode derivative is written out (Rasmussen & Williams 2006, eq. 5.9):
    ``d/dr = -K^-1 r`` and ``d/dK = (alpha alpha^T - K^-1) / 2`` with ``alpha = K^-1 r``,
    which is cheaper than differentiating through the Cholesky factorisation.
    """
    return _mvn_fwd(r, K)[0]


def _mvn_fwd(r, K):
    L = jnp.linalg.cholesky(K)
    a = jsl.solve_triangular(L, r, lower=True)
    value = -0.5 * a @ a - jnp.sum(jnp.log(jnp.diag(L))) - 0.5 * r.shape[0] * _LOG_2PI
    alpha = jsl.solve_triangular(L, a, lower=True, trans=1)
    return value, (L, alpha)


def _mvn_bwd(res, g):
    L, alpha = res
    K_inv = jsl.cho_solve((L, True), jnp.eye(L.shape[0], dtype=L.dtype))
    return -g * alpha, 0.5 * g * (jnp.outer(alpha, alpha) - K_inv)


mvn_logpdf_chol.defvjp(_mvn_fwd, _mvn_bwd)


@jax.custom_jvp
def finite_or_neg_inf(x):
    """``x`` where finite, ``-inf`` elsewhere (NaN included); the tangent passes unchanged.

    A plain ``jnp.where`` would put a select into the whole reverse pass (measured 25 %
    slower on the koh_anchor gradient); where the value is ``-inf`` the sampler rejects the
    point whatever the gradient is.
    """
    return jnp.where(jnp.isfinite(x), x, -jnp.inf)


@finite_or_neg_inf.defjvp
def _finite_jvp(primals, tangents):
    return finite_or_neg_inf(primals[0]), tangents[0]


@dataclass(frozen=True)
class KOHSpec:
    """Static (hashable) part of a KOH log-density; see the module docstring.

    Layout of the unconstrained vector ``u``: ``theta`` (p, through each prior's bijection),
    then the free hyperparameters in the order ``ell`` (q), ``sd2``, ``se2``, each through
    its prior's bijection (the log for the default priors).
    """

    mean_fn: Callable
    theta_priors: tuple[Prior, ...]
    ell_priors: tuple[Prior, ...]
    sd2_prior: Prior
    se2_prior: Prior
    fixed: tuple[str, ...] = ()
    emulator_var_fn: Callable | None = None
    with_mean_args: bool = False

    @property
    def p(self) -> int:
        return len(self.theta_priors)

    @property
    def q(self) -> int:
        return len(self.ell_priors)

    @property
    def dim(self) -> int:
        return (self.p + (0 if "ell" in self.fixed else self.q)
                + (0 if "sd2" in self.fixed else 1) + (0 if "se2" in self.fixed else 1))

    def _blocks(self):
        """(name, priors, size) of the blocks of ``u``, in order."""
        blocks = [("theta", self.theta_priors)]
        if "ell" not in self.fixed:
            blocks.append(("ell", self.ell_priors))
        for name, prior in (("sd2", self.sd2_prior), ("se2", self.se2_prior)):
            if name not in self.fixed:
                blocks.append((name, (prior,)))
        return blocks

    def _unpack(self, data, u):
        """Constrained values and the summed log prior density of ``u`` (incl. Jacobian)."""
        priors = [pr for _, block in self._blocks() for pr in block]
        xs, lp = [], 0.0
        for start, stop, stacked in stack_priors(priors):  # vectorised runs of one class
            xs.append(stacked.to_constrained(u[start:stop]))
            lp = lp + jnp.sum(stacked.log_prob_unconstrained(u[start:stop]))
        x = jnp.concatenate(xs) if len(xs) > 1 else xs[0]
        out, i = {}, 0
        for name, block in self._blocks():
            out[name] = x[i:i + len(block)] if name in ("theta", "ell") else x[i]
            i += len(block)
        for name in self.fixed:
            out[name] = data["fixed"][name]
        return out, lp

    def _mean(self, data, theta):
        if self.with_mean_args:
            return self.mean_fn(theta, data["mean_args"])
        return self.mean_fn(theta)

    def _emulator_var(self, data, theta):
        if self.with_mean_args:
            return self.emulator_var_fn(theta, data["mean_args"])
        return self.emulator_var_fn(theta)

    def covariance(self, data, ell, sd2, se2, theta=None):
        """KOH covariance ``C_delta(X, X) + se2 I [+ diag(var)]``, (n, n)."""
        # method.md section 3: squared-exponential discrepancy on unit-cube inputs
        K = sd2 * jnp.exp(-0.5 * jnp.sum(data["d2x"] / ell**2, axis=-1))
        eye = jnp.eye(K.shape[0], dtype=K.dtype)
        if self.emulator_var_fn is not None:
            return K + eye * (se2 + self._emulator_var(data, theta))
        return K + se2 * eye

    def loglik(self, data, theta, ell, sd2, se2):
        """Log-likelihood of the data with the discrepancy integrated out (scalar)."""
        r = data["y"] - self._mean(data, theta)
        return mvn_logpdf_chol(r, self.covariance(data, ell, sd2, se2, theta))

    def logdensity(self, data, u):
        """Unnormalised log posterior density of ``u`` (dim,); ``-inf`` where non-finite."""
        c, lp = self._unpack(data, u)
        return finite_or_neg_inf(lp + self.loglik(data, c["theta"], c["ell"], c["sd2"], c["se2"]))

    def constrain(self, data, u):
        """``dict(theta=(p,), ell=(q,), sd2=(), se2=())`` from ``u`` (dim,)."""
        c, _ = self._unpack(data, u)
        return {"theta": c["theta"], "ell": c["ell"], "sd2": c["sd2"], "se2": c["se2"]}

    def unconstrain(self, values: Mapping[str, Any]):
        """Inverse of :meth:`constrain` (fixed hyperparameters are ignored), (dim,)."""
        parts = []
        for name, priors in self._blocks():
            v = jnp.atleast_1d(jnp.asarray(values[name], dtype=float))
            if v.shape != (len(priors),):
                raise CalibrationError(
                    f"unconstrain: expected {name} of shape ({len(priors)},), got {v.shape}")
            parts += [prior.to_unconstrained(v[j]) for j, prior in enumerate(priors)]
        return jnp.stack(parts)

    def init(self, seed, n_chains: int):
        """Prior draws on the unconstrained scale, (n_chains, dim); ``seed``: int or Generator."""
        return init_from_priors(self._blocks(), seed, n_chains)


@dataclass(frozen=True)
class KOHLogDensity:
    """A KOH log-density bound to its data; build it with :func:`build_logdensity`.

    Attributes
    ----------
    spec : KOHSpec
        Hashable static part (key of compiled samplers).
    data : dict
        Pytree of arrays: ``y`` (n,), ``d2x`` (n, n, q), ``mean_args``, ``fixed``.
    name : str
        Model name used in messages.
    theta_names, x_names : tuple of str
        Names of the calibration parameters (p) and of the discrepancy inputs (q).
    """

    spec: KOHSpec
    data: dict = field(repr=False)
    name: str = "model"
    theta_names: tuple[str, ...] = ()
    x_names: tuple[str, ...] = ()

    @property
    def dim(self) -> int:
        """Length of the unconstrained vector ``u``."""
        return self.spec.dim

    @property
    def n_obs(self) -> int:
        return int(self.data["y"].shape[0])

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the coordinates of ``u`` (unconstrained scale)."""
        out = [f"theta[{n}]" for n in self.theta_names]
        if "ell" not in self.spec.fixed:
            out += [f"ell[{n}]" for n in self.x_names]
        out += [n for n in ("sd2", "se2") if n not in self.spec.fixed]
        return tuple(out)

    @property
    def sampled_vars(self) -> tuple[str, ...]:
        """Posterior variables that are sampled (fixed hyperparameters excluded)."""
        return ("theta",) + tuple(h for h in HYPERPARAMETERS if h not in self.spec.fixed)

    @property
    def dims(self) -> dict[str, list[str]]:
        return {"theta": ["theta_dim"], "ell": ["ell_dim"]}

    @property
    def coords(self) -> dict[str, list[str]]:
        return {"theta_dim": list(self.theta_names), "ell_dim": list(self.x_names)}

    def logdensity(self, u):
        """Pure JAX log posterior density of ``u`` (dim,) on the unconstrained scale."""
        return self.spec.logdensity(self.data, u)

    def constrain(self, u):
        """``dict(theta=(p,), ell=(q,), sd2, se2)`` from ``u`` (dim,)."""
        return self.spec.constrain(self.data, u)

    def unconstrain(self, values: Mapping[str, Any]):
        """``u`` (dim,) from a dict with keys theta, ell, sd2, se2 (fixed ones ignored)."""
        return self.spec.unconstrain(values)

    def init(self, seed: int, n_chains: int):
        """Initial points drawn from the priors, (n_chains, dim), unconstrained scale."""
        return self.spec.init(seed, n_chains)


def _as_prior_tuple(prior, q: int, what: str) -> tuple[Prior, ...]:
    priors = (prior,) * q if isinstance(prior, Prior) else tuple(prior)
    if len(priors) != q or not all(isinstance(p, Prior) for p in priors):
        raise CalibrationError(f"{what}: expected one Prior or a sequence of {q} Priors, "
                               f"got {prior!r}")
    return priors


def _check_positive_prior(prior: Prior, what: str) -> None:
    if prior.support[0] < 0:
        raise CalibrationError(f"{what}: expected a prior on (0, inf) such as LogNormal or "
                               f"InverseGamma, got {prior!r}")


def _fixed_values(fixed: Mapping[str, Any] | None, q: int) -> dict[str, Any]:
    out = {}
    for key, value in (fixed or {}).items():
        if key not in HYPERPARAMETERS:
            raise CalibrationError(f"fixed: unknown hyperparameter {key!r}; "
                                   f"expected some of {HYPERPARAMETERS}")
        v = np.asarray(value, dtype=float)
        if key == "ell":
            v = np.broadcast_to(v, (q,)).copy()
        elif v.shape != ():
            raise CalibrationError(f"fixed: {key} must be a scalar, got shape {v.shape}")
        if not np.all(np.isfinite(v)) or np.any(v < 0) or (key == "ell" and np.any(v == 0)):
            raise CalibrationError(f"fixed: {key} must be finite and positive, got {v}")
        out[key] = jnp.asarray(v)
    return out


def build_logdensity(
    mean_fn: Callable,
    y,
    x_disc,
    *,
    theta_priors: Sequence[Prior],
    ell_prior: Prior | Sequence[Prior] = DEFAULT_ELL_PRIOR,
    sd2_prior: Prior = DEFAULT_VARIANCE_PRIOR,
    se2_prior: Prior = DEFAULT_VARIANCE_PRIOR,
    emulator_var_fn: Callable | None = None,
    mean_args: Any = None,
    fixed: Mapping[str, Any] | None = None,
    name: str = "model",
    theta_names: Sequence[str] | None = None,
    x_names: Sequence[str] | None = None,
) -> KOHLogDensity:
    """Build the KOH log posterior density of one model (method.md section 3).

    Parameters
    ----------
    mean_fn : callable
        ``theta (p,) -> (n,)``: surrogate mean at the experimental settings, on the
        standardised output scale; ``(theta, mean_args) -> (n,)`` when ``mean_args`` is
        given. Pure JAX. Pass a module-level function and the arrays it needs as
        ``mean_args`` so that calibrations of the same shapes reuse one compiled sampler.
    y : array, (n,)
        Standardised observations.
    x_disc : array, (n, q)
        Control inputs of the observations scaled to the unit cube (discrepancy inputs).
    theta_priors : sequence of Prior, length p
        Priors of the calibration parameters (e.g. :class:`~calnet.calibration.priors.Beta`).
    ell_prior, sd2_prior, se2_prior : Prior
        Priors of the discrepancy length scales (one prior or q of them), discrepancy
        variance and noise variance. Defaults: LogNormal(0, 0.5), InverseGamma(2, 1) twice.
    emulator_var_fn : callable, optional
        ``theta -> (n,)`` (or ``(theta, mean_args) -> (n,)``) predictive variance of the
        surrogate, added to the diagonal of the covariance (emulator uncertainty on).
    mean_args : pytree of arrays, optional
        Data passed to ``mean_fn`` and ``emulator_var_fn``.
    fixed : dict, optional
        Hyperparameters held at known values instead of sampled: any of
        ``ell`` (scalar or (q,)), ``sd2``, ``se2``.
    name : str
        Model name used in errors and warnings.
    theta_names, x_names : sequence of str, optional
        Names of the parameters and discrepancy inputs (defaults ``theta_0``, ``x_0`` ...).

    Returns
    -------
    KOHLogDensity

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from calnet.calibration.priors import Normal
    >>> ld = build_logdensity(lambda th: th[0] * jnp.ones(3), jnp.zeros(3),
    ...                       jnp.array([[0.0], [0.5], [1.0]]), theta_priors=[Normal(0, 1)])
    >>> ld.dim
    4
    """
    y = np.asarray(y, dtype=float)
    x = np.asarray(x_disc, dtype=float)
    if y.ndim != 1 or not np.all(np.isfinite(y)):
        raise CalibrationError(f"{name}: expected finite observations y of shape (n,), "
                               f"got shape {y.shape}")
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or x.shape[0] != y.shape[0] or not np.all(np.isfinite(x)):
        raise CalibrationError(f"{name}: expected finite x_disc of shape ({y.shape[0]}, q), "
                               f"got shape {x.shape}")
    n, q = x.shape
    theta_priors = tuple(theta_priors)
    if not theta_priors or not all(isinstance(p, Prior) for p in theta_priors):
        raise CalibrationError(f"{name}: theta_priors must be a non-empty sequence of Prior")
    ell_priors = _as_prior_tuple(ell_prior, q, f"{name}: ell_prior")
    for what, prior in [("ell_prior", p) for p in ell_priors] + [
            ("sd2_prior", sd2_prior), ("se2_prior", se2_prior)]:
        _check_positive_prior(prior, f"{name}: {what}")
    fixed_vals = _fixed_values(fixed, q)
    spec = KOHSpec(mean_fn, theta_priors, ell_priors, sd2_prior, se2_prior,
                   fixed=tuple(h for h in HYPERPARAMETERS if h in fixed_vals),
                   emulator_var_fn=emulator_var_fn, with_mean_args=mean_args is not None)
    # pairwise squared differences of the discrepancy inputs, computed once: (n, n, q)
    d2x = (x[:, None, :] - x[None, :, :]) ** 2
    data = {"y": jnp.asarray(y), "d2x": jnp.asarray(d2x), "fixed": fixed_vals}
    if mean_args is not None:
        data["mean_args"] = jax.tree.map(jnp.asarray, mean_args)
    theta_names = tuple(theta_names or (f"theta_{i}" for i in range(len(theta_priors))))
    x_names = tuple(x_names or (f"x_{j}" for j in range(q)))
    if len(theta_names) != len(theta_priors) or len(x_names) != q:
        raise CalibrationError(f"{name}: expected {len(theta_priors)} theta_names and {q} "
                               f"x_names, got {len(theta_names)} and {len(x_names)}")
    ld = KOHLogDensity(spec, data, name, theta_names, x_names)
    _check_mean_shape(ld)
    if n < ld.dim:
        warnings.warn(
            f"{name}: {n} data points for {ld.dim} sampled parameters (calibration "
            f"parameters and discrepancy hyperparameters); the posterior will lean on the "
            f"priors - add data or fix hyperparameters with fixed=",
            CalibrationWarning, stacklevel=2)
    return ld


def _check_mean_shape(ld: KOHLogDensity) -> None:
    theta = jnp.zeros(ld.spec.p)
    fns = [("mean_fn", ld.spec._mean)]
    if ld.spec.emulator_var_fn is not None:
        fns.append(("emulator_var_fn", ld.spec._emulator_var))
    for what, fn in fns:
        try:
            out = jax.eval_shape(fn, ld.data, theta)
        except Exception as exc:  # user code: report which model and function failed
            raise CalibrationError(f"{ld.name}: {what} failed on a theta of shape "
                                   f"({ld.spec.p},): {exc}") from exc
        if getattr(out, "shape", None) != (ld.n_obs,):
            raise CalibrationError(f"{ld.name}: {what} must return shape ({ld.n_obs},), "
                                   f"got {getattr(out, 'shape', out)}")


def _value_and_grad(spec, data, u):
    return jax.vmap(jax.value_and_grad(spec.logdensity, argnums=1), in_axes=(None, 0))(data, u)


_value_and_grad_jit = jax.jit(_value_and_grad, static_argnums=0)


def check_initial(ld, u0, model_name: str | None = None) -> None:
    """Raise :class:`~calnet.errors.CalibrationError` if the log-density or its gradient is
    non-finite at any initial point.

    Parameters
    ----------
    ld : KOHLogDensity (or any object with ``spec`` and ``data``)
    u0 : array, (n_chains, dim) or (dim,)
        Initial points on the unconstrained scale.
    model_name : str, optional
        Name used in the message (default ``ld.name``).
    """
    name = model_name or getattr(ld, "name", "model")
    u0 = jnp.atleast_2d(jnp.asarray(u0, dtype=float))
    values, grads = _value_and_grad_jit(ld.spec, ld.data, u0)
    values, grads = np.asarray(values), np.asarray(grads)
    bad_value = ~np.isfinite(values)
    bad_grad = ~np.all(np.isfinite(grads), axis=1)
    if bad_value.any() or bad_grad.any():
        chains = np.flatnonzero(bad_value | bad_grad).tolist()
        what = "log-density" if bad_value.any() else "gradient of the log-density"
        raise CalibrationError(
            f"model {name!r}: the {what} is not finite at the initial point(s) of chain(s) "
            f"{chains} (values {values.tolist()}); check that the surrogate mean is finite "
            "for parameters inside their bounds, that the data are standardised and finite, "
            "and that fixed hyperparameters are positive")
