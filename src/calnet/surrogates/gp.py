"""The fitted Gaussian-process surrogate: an immutable pytree with pure predict functions.

:func:`condition` builds a :class:`FittedGP` from data and given hyperparameters (the low
level); :func:`calnet.surrogates.fit_gp` chooses the hyperparameters and calls it.

Scales: inputs are given in physical units and scaled to the unit cube with the
``lower``/``upper`` bounds; outputs are transformed (``log`` or not) to the *modelled*
scale, then standardised. ``predict`` returns mean and variance on the modelled scale;
:meth:`FittedGP.to_natural` maps them back.

Mean function: zero on the standardised scale (``mean="constant"``, the outputs' mean), or
a trend in the unit-cube inputs, ``h(x)^T beta`` with ``h = [1, x]`` (``"linear"``) or
``[1, x, x_i x_j]`` (``"quadratic"``, :func:`~calnet.surrogates.likelihood.basis`):
``beta`` is the generalised least-squares estimate and the predictive variance carries
its uncertainty, ``u^T (H^T K^-1 H)^-1 u`` with ``u = h(x) - H^T K^-1 k(X, x)`` (universal
kriging; Rasmussen and Williams 2006, eq. 2.42). A trend that a stationary kernel would
have to carry as a large, long-range signal variance then costs no variance at all.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from calnet.errors import SurrogateError
from calnet.surrogates.kernels import (
    _matern32_corr,
    matern32,
    matern32_from_sqdist,
    scaled_sqdist,
)
from calnet.surrogates.likelihood import (
    basis,
    mean_of,
    neg_log_marginal_likelihood,
    predictive_solve,
)

ARRAY_FIELDS = ("x_train", "alpha", "chol", "lengthscales", "signal_var", "nugget",
                "lower", "upper", "y_mean", "y_std", "nlml", "beta", "basis_solve",
                "basis_chol")
#: the arrays of the mean function, empty for a constant mean (files without them load so)
TREND_FIELDS = ("beta", "basis_solve", "basis_chol")
META_FIELDS = ("transform", "name")


def constant_mean(n_train: int) -> dict[str, jax.Array]:
    """The :data:`TREND_FIELDS` of a constant mean (no basis column) for ``n_train`` runs."""
    return {"beta": jnp.zeros(0), "basis_solve": jnp.zeros((n_train, 0)),
            "basis_chol": jnp.zeros((0, 0))}


@dataclass(frozen=True)
class FittedGP:
    """A Matern 3/2 ARD GP conditioned on training data. Build with :func:`fit_gp`.

    Attributes
    ----------
    x_train : array, shape (n_train, d)
        Training inputs scaled to the unit cube.
    alpha : array, shape (n_train,)
        ``K^-1 (y_s - H beta)``, with ``y_s`` the standardised training outputs.
    chol : array, shape (n_train, n_train)
        Lower Cholesky factor of ``K = s2 * Matern(x_train) + nugget * I``.
    lengthscales : array, shape (d,)
        ARD length scales in unit-cube units.
    signal_var, nugget : scalar arrays
        Signal variance and nugget in standardised-output units.
    lower, upper : array, shape (d,)
        Input bounds in physical units that define the unit cube.
    y_mean, y_std : scalar arrays
        Standardisation of the modelled-scale output.
    nlml : scalar array
        Negative log marginal likelihood of the standardised outputs at these
        hyperparameters, restricted (REML) with a trend (``nan`` if the
        hyperparameters were given, not fitted).
    beta : array, shape (p,)
        Coefficients of the mean function on the standardised scale: ``p = 0`` for a
        constant mean, ``d + 1`` (intercept, then one per unit-cube input) for a linear
        one, ``(d + 1)(d + 2) / 2`` for a quadratic one.
    basis_solve : array, shape (n_train, p)
        ``L^-1 H``, ``H`` the mean function's basis at the training inputs.
    basis_chol : array, shape (p, p)
        Lower Cholesky factor of ``H^T K^-1 H``.
    transform : {None, "log"}
        Output transform: the modelled scale is ``log(y)`` when ``"log"``.
    name : str
        Output name, used in messages and by the integrator.
    """

    x_train: jax.Array
    alpha: jax.Array
    chol: jax.Array
    lengthscales: jax.Array
    signal_var: jax.Array
    nugget: jax.Array
    lower: jax.Array
    upper: jax.Array
    y_mean: jax.Array
    y_std: jax.Array
    nlml: jax.Array
    beta: jax.Array
    basis_solve: jax.Array
    basis_chol: jax.Array
    transform: str | None = None
    name: str = ""

    @property
    def mean(self) -> str:
        """``"constant"``, ``"linear"`` or ``"quadratic"``: the mean function."""
        return mean_of(self.beta.shape[0], self.x_train.shape[1])

    @property
    def n_train(self) -> int:
        """Number of training points."""
        return int(self.x_train.shape[0])

    @property
    def n_inputs(self) -> int:
        """Number of inputs ``d``."""
        return int(self.x_train.shape[1])

    def scale_inputs(self, z: jax.Array) -> jax.Array:
        """Map physical inputs (..., d) to unit-cube units."""
        return (jnp.asarray(z) - self.lower) / (self.upper - self.lower)

    def predict(self, z: jax.Array, *, include_nugget: bool = False) -> tuple[jax.Array, jax.Array]:
        """Predictive mean and variance at new inputs, on the modelled scale.

        Pure and jit-able (``jax.jit(gp.predict)``, or pass ``gp`` as a pytree argument).

        Parameters
        ----------
        z : array, shape (m, d)
            Inputs in physical units.
        include_nugget : bool, default False
            Add the nugget to the variance: the variance of a new *simulator run* rather
            than of the latent smooth function.

        Returns
        -------
        mean : array, shape (m,)
            Modelled-scale mean (``log`` units when ``transform == "log"``).
        var : array, shape (m,)
            Modelled-scale variance, >= 0.
        """
        return _predict(self, jnp.asarray(z, dtype=jnp.float64), include_nugget)

    def predict_mean(self, z: jax.Array) -> jax.Array:
        """Predictive mean (m,) at inputs ``z`` (m, d) in physical units, on the modelled
        scale: :meth:`predict`'s mean without its variance (no solve with the training
        covariance). Pure and jit-able; its derivative by ``z`` is written out
        (:meth:`mean_gradient`), so a Jacobian by many directions (forward mode) costs
        one kernel evaluation, not one per direction. Not differentiable by the GP's own
        arrays (its hyperparameters and training data)."""
        return _predict_mean(self, jnp.atleast_2d(jnp.asarray(z, dtype=jnp.float64)))

    def mean_gradient(self, z: jax.Array) -> jax.Array:
        """Gradient (m, d) of the predictive mean by the physical inputs ``z`` (m, d),
        modelled scale. For the Matern 3/2 kernel ``dk/dz_j = -3 s2 e^(-r) (z_j -
        X_j) / ell_j^2`` (unit-cube units, ``r = sqrt(3 r2)``), finite at ``r = 0``."""
        zs = self.scale_inputs(jnp.atleast_2d(jnp.asarray(z, dtype=jnp.float64)))
        r2 = scaled_sqdist(zs, self.x_train, self.lengthscales)
        w = -3.0 * self.signal_var * jnp.exp(-jnp.sqrt(3.0 * jnp.maximum(r2, 0.0))) \
            * self.alpha[None, :]  # (m, n)
        grad = (zs * jnp.sum(w, axis=1, keepdims=True) - w @ self.x_train) \
            / self.lengthscales**2
        if self.beta.shape[0]:
            grad = grad + jax.vmap(jax.grad(lambda row: self._trend(row[None])[0]))(zs)
        return self.y_std * grad / (self.upper - self.lower)

    def predict_cov(self, z: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Predictive mean (m,) and covariance (m, m) of the latent function at inputs
        ``z`` (m, d) in physical units, on the modelled scale. Pure and jit-able."""
        zs = self.scale_inputs(jnp.atleast_2d(jnp.asarray(z, dtype=jnp.float64)))
        k_star = matern32(zs, self.x_train, self.lengthscales, self.signal_var)
        v = predictive_solve(self.chol, k_star)  # (n_train, m)
        cov = matern32(zs, zs, self.lengthscales, self.signal_var) - v.T @ v
        if self.beta.shape[0]:
            q = self._trend_solve(zs, v)
            cov = cov + q.T @ q
        return (self.y_mean + self.y_std * (self._trend(zs) + k_star @ self.alpha),
                self.y_std**2 * cov)

    def at_controls(self, x: jax.Array) -> dict[str, jax.Array]:
        """What :meth:`moments_at` needs at fixed control inputs ``x`` (m, d_x), already
        in the GP's input space (logs taken), physical units: the control-input part of
        the scaled squared distances to the training points ``r2_train`` (m, n_train)
        and among the points ``r2_among`` (m, m), and the parameter columns of the
        training inputs rescaled so that a parameter vector needs one multiply,
        ``theta_train`` (n_train, d_theta) and ``theta_scale`` (d_theta,), the mean's
        weights on the modelled scale ``weights`` (n_train,) and the control inputs on
        the unit cube ``x_unit`` (m, d_x), for the mean function. The predictive at many
        parameter values then costs the parameter part only."""
        dx = x.shape[1]
        span = self.upper - self.lower
        xs = (x - self.lower[:dx]) / span[:dx]
        scale = 1.0 / (span[dx:] * self.lengthscales[dx:])  # physical theta -> scaled
        return {"r2_train": scaled_sqdist(xs, self.x_train[:, :dx], self.lengthscales[:dx]),
                "r2_among": scaled_sqdist(xs, xs, self.lengthscales[:dx]),
                "theta_train": self.x_train[:, dx:] / self.lengthscales[dx:]
                + self.lower[dx:] * scale,
                "theta_scale": scale,
                "weights": self.y_std * self.signal_var * self.alpha,
                "x_unit": xs}

    def moments_at(self, fixed: dict[str, jax.Array], theta: jax.Array, *,
                   cov: bool) -> tuple[jax.Array, jax.Array | None]:
        """Mean (m,) and, if ``cov``, covariance (m, m) at fixed control inputs (``fixed``
        from :meth:`at_controls`) and parameters ``theta`` (d_theta,) in the GP's input
        space; modelled scale."""
        r2t = jnp.sum((theta * fixed["theta_scale"] - fixed["theta_train"]) ** 2, axis=-1)
        corr = _matern32_corr(fixed["r2_train"] + r2t[None, :])
        mean = self.y_mean + corr @ fixed["weights"]
        zs = None
        if self.beta.shape[0]:
            zs = self._with_theta(fixed["x_unit"], theta)
            mean = mean + self.y_std * self._trend(zs)
        if not cov:
            return mean, None
        k = self.signal_var * corr
        v = predictive_solve(self.chol, k)
        kss = matern32_from_sqdist(fixed["r2_among"], self.signal_var) - v.T @ v
        if zs is not None:
            q = self._trend_solve(zs, v)
            kss = kss + q.T @ q
        return mean, self.y_std**2 * kss

    def predict_split(
        self, x: jax.Array, theta: jax.Array, *, include_nugget: bool = False
    ) -> tuple[jax.Array, jax.Array]:
        """:meth:`predict` with control inputs and calibration parameters given apart.

        Parameters
        ----------
        x : array, shape (m, d_x)
            Control inputs (the first ``d_x`` columns of the GP's inputs), physical units.
        theta : array, shape (d_theta,) or (m, d_theta)
            Calibration parameters (the remaining columns); a vector is used for every row.
        """
        x = self._check_controls(x)
        theta = jnp.broadcast_to(jnp.asarray(theta), (x.shape[0], self.n_inputs - x.shape[1]))
        return self.predict(jnp.concatenate([x, theta], axis=1), include_nugget=include_nugget)

    def mean_fn_at(self, x: jax.Array) -> Callable[[jax.Array], jax.Array]:
        """Fast mean ``theta -> mean(x, theta)`` at fixed control inputs.

        The control-input part of the scaled squared distances to the training points is
        computed once here; each call then costs ``O(n_train * (d_theta + m))``. The
        returned closure is pure JAX: jit-, grad- and vmap-able.

        Parameters
        ----------
        x : array, shape (m, d_x)
            Control inputs in physical units.

        Returns
        -------
        callable
            ``f(theta)`` with theta shape (d_theta,) returning the modelled-scale mean,
            shape (m,).
        """
        r2_x, to_r2, xs = self._split_distances(x)
        coef = self.y_std * self.signal_var * self.alpha
        y_mean = self.y_mean

        def mean(theta: jax.Array) -> jax.Array:
            corr = matern32_from_sqdist(r2_x + to_r2(theta), 1.0)
            out = y_mean + corr @ coef
            if self.beta.shape[0]:
                out = out + self.y_std * self._trend(self._with_theta(xs, theta))
            return out

        return mean

    def var_fn_at(
        self, x: jax.Array, *, include_nugget: bool = False
    ) -> Callable[[jax.Array], jax.Array]:
        """Fast variance ``theta -> var(x, theta)`` at fixed control inputs.

        Same precomputation as :meth:`mean_fn_at`; each call costs a triangular solve,
        ``O(m * n_train^2)``.

        Returns
        -------
        callable
            ``f(theta)`` with theta shape (d_theta,) returning the modelled-scale
            variance, shape (m,).
        """
        r2_x, to_r2, xs = self._split_distances(x)

        def var(theta: jax.Array) -> jax.Array:
            k_star = matern32_from_sqdist(r2_x + to_r2(theta), self.signal_var)
            return self._moments(self._with_theta(xs, theta), k_star, include_nugget)[1]

        return var

    def to_natural(self, mean: jax.Array, var: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Map modelled-scale moments to the natural (physical) output scale.

        With ``transform == "log"`` the prediction is lognormal and this returns its mean
        ``exp(mu + var / 2)`` and variance ``(exp(var) - 1) exp(2 mu + var)``. (The median
        is ``exp(mu)``, and 95 % intervals are best taken as ``exp(mu +- 1.96 sqrt(var))``
        on the modelled scale.) Without a transform the moments are returned unchanged.

        Parameters
        ----------
        mean, var : array, shape (m,)
            Modelled-scale moments from :meth:`predict`.

        Returns
        -------
        mean, var : array, shape (m,)
        """
        if self.transform == "log":
            return jnp.exp(mean + 0.5 * var), jnp.expm1(var) * jnp.exp(2.0 * mean + var)
        return mean, var

    def log_marginal_likelihood(self, log_params: jax.Array | None = None) -> jax.Array:
        """Log marginal likelihood of the standardised training outputs.

        Parameters
        ----------
        log_params : array, shape (d + 2,), optional
            ``[log ell, log s2, log nugget]``; defaults to the fitted ones.
        """
        if log_params is None:
            log_params = self.log_params
        return _log_marginal_likelihood(self, jnp.asarray(log_params))

    @property
    def log_params(self) -> jax.Array:
        """``[log ell (d), log s2, log nugget]``, shape (d + 2,)."""
        return jnp.log(jnp.concatenate(
            [self.lengthscales, jnp.stack([self.signal_var, self.nugget])]))

    # -- internals ---------------------------------------------------------------------

    def _trend(self, zs: jax.Array) -> jax.Array | float:
        """The mean function at unit-cube inputs ``zs`` (m, d), standardised scale."""
        if not self.beta.shape[0]:
            return 0.0
        return basis(zs, self.mean) @ self.beta

    def _trend_solve(self, zs: jax.Array, v: jax.Array) -> jax.Array:
        """``R^-1 u`` (p, m) with ``u = h(zs) - H^T K^-1 k_*`` (``v = L^-1 k_*``, (n, m))
        and ``R R^T = H^T K^-1 H``: the mean function's share of the variance is
        ``sum(q**2, axis=0)``, standardised scale."""
        u = basis(zs, self.mean).T - self.basis_solve.T @ v
        return jax.scipy.linalg.solve_triangular(self.basis_chol, u, lower=True)

    def _with_theta(self, xs: jax.Array, theta: jax.Array) -> jax.Array:
        """Unit-cube inputs (m, d): control inputs ``xs`` (m, d_x), already on the unit
        cube, and one physical parameter vector ``theta`` (d_theta,)."""
        dx = xs.shape[1]
        t = (theta - self.lower[dx:]) / (self.upper[dx:] - self.lower[dx:])
        return jnp.concatenate([xs, jnp.broadcast_to(t, (xs.shape[0], t.shape[0]))], axis=1)

    def _moments(self, zs: jax.Array, k_star: jax.Array, include_nugget: bool
                 ) -> tuple[jax.Array, jax.Array]:
        mean_s = self._trend(zs) + k_star @ self.alpha
        v = predictive_solve(self.chol, k_star)
        var_s = self.signal_var - jnp.sum(v * v, axis=0)
        if self.beta.shape[0]:
            var_s = var_s + jnp.sum(self._trend_solve(zs, v) ** 2, axis=0)
        var_s = jnp.maximum(var_s, 0.0)
        if include_nugget:
            var_s = var_s + self.nugget
        return self.y_mean + self.y_std * mean_s, self.y_std**2 * var_s

    def _check_controls(self, x) -> jax.Array:
        x = jnp.atleast_2d(jnp.asarray(x, dtype=jnp.float64))
        if x.ndim != 2 or not 0 < x.shape[1] < self.n_inputs:
            lab = f"output {self.name!r}" if self.name else "surrogate"
            raise SurrogateError(f"{lab}: control inputs x must have shape (m, d_x) with "
                                 f"0 < d_x < {self.n_inputs}, got {x.shape}")
        return x

    def _split_distances(self, x: jax.Array):
        x = self._check_controls(x)
        dx = x.shape[1]
        xs = (x - self.lower[:dx]) / (self.upper[:dx] - self.lower[:dx])
        r2_x = scaled_sqdist(xs, self.x_train[:, :dx], self.lengthscales[:dx])
        ell_t = self.lengthscales[dx:]
        xt = self.x_train[:, dx:] / ell_t  # (n, d_theta)
        lo, span = self.lower[dx:], self.upper[dx:] - self.lower[dx:]

        def to_r2(theta: jax.Array) -> jax.Array:
            t = (theta - lo) / span / ell_t
            diff = xt - t
            return jnp.sum(diff * diff, axis=-1)[None, :]  # (1, n)

        return r2_x, to_r2, xs


jax.tree_util.register_dataclass(FittedGP, data_fields=list(ARRAY_FIELDS),
                                 meta_fields=list(META_FIELDS))


@jax.custom_jvp
def _predict_mean(gp: FittedGP, z: jax.Array) -> jax.Array:
    zs = gp.scale_inputs(z)
    k_star = matern32(zs, gp.x_train, gp.lengthscales, gp.signal_var)
    return gp.y_mean + gp.y_std * (gp._trend(zs) + k_star @ gp.alpha)


@_predict_mean.defjvp
def _predict_mean_jvp(primals, tangents):
    # the GP's arrays are data, not variables: their tangents are not used
    gp, z = primals
    z_dot = tangents[1]
    return _predict_mean(gp, z), jnp.sum(gp.mean_gradient(z) * z_dot, axis=-1)


@partial(jax.jit, static_argnums=2)
def _predict(gp: FittedGP, z: jax.Array, include_nugget: bool):
    zs = gp.scale_inputs(jnp.atleast_2d(z))
    k_star = matern32(zs, gp.x_train, gp.lengthscales, gp.signal_var)
    return gp._moments(zs, k_star, include_nugget)


@jax.jit
def _log_marginal_likelihood(gp: FittedGP, log_params: jax.Array) -> jax.Array:
    H = basis(gp.x_train, gp.mean)
    # K alpha + H beta: the standardised training outputs
    y_s = gp.chol @ (gp.chol.T @ gp.alpha) + gp._trend(gp.x_train)
    return -neg_log_marginal_likelihood(log_params, gp.x_train, y_s, H)


@partial(jax.jit, static_argnums=(7, 8))
def _condition_arrays(x, y, lower, upper, ell, s2, nug, log: bool, mean: str):
    xs = (x - lower) / (upper - lower)
    z = jnp.log(y) if log else y
    y_mean, y_std = jnp.mean(z), jnp.std(z)
    ys = (z - y_mean) / y_std
    k = matern32(xs, xs, ell, s2) + nug * jnp.eye(xs.shape[0], dtype=xs.dtype)
    chol = jnp.linalg.cholesky(k)
    alpha, beta, w, r = _weights(chol, basis(xs, mean), ys)
    return xs, alpha, chol, y_mean, y_std, beta, w, r


def _weights(chol, H, ys):
    """``(alpha, beta, w, r)`` of standardised outputs ``ys`` (n,) under the covariance
    with Cholesky factor ``chol`` and the mean function's basis ``H`` (n, p): the trend's
    generalised least-squares coefficients ``beta = (H^T K^-1 H)^-1 H^T K^-1 y_s``,
    ``alpha = K^-1 (y_s - H beta)``, ``w = L^-1 H`` and ``r`` the Cholesky factor of
    ``w^T w`` (for a constant mean, no column: ``beta`` and ``r`` empty)."""
    if not H.shape[1]:
        return (jax.scipy.linalg.cho_solve((chol, True), ys), jnp.zeros(0, ys.dtype), H,
                jnp.zeros((0, 0), ys.dtype))
    w = jax.scipy.linalg.solve_triangular(chol, H, lower=True)
    r = jnp.linalg.cholesky(w.T @ w)
    a = jax.scipy.linalg.solve_triangular(chol, ys, lower=True)
    beta = jax.scipy.linalg.cho_solve((r, True), w.T @ a)
    return jax.scipy.linalg.cho_solve((chol, True), ys - H @ beta), beta, w, r


@partial(jax.jit, static_argnums=6)
def held_out_moments(xs, ys, keep, ell, s2, nug, mean: str):
    """Predictive mean and variance (a new run's: the nugget included), standardised
    scale, at every one of the points ``xs`` (n, d) (unit cube) of a GP conditioned on
    those of ``keep`` 1 alone, with hyperparameters ``ell``, ``s2``, ``nug``: the
    cross-validation fold's predictions at its held-out points (``keep`` 0), in arrays
    of the full shape, so that every fold runs one compiled program. ``ys`` (n,) are the
    kept points' standardised outputs, zero elsewhere. The held-out points' rows and
    columns of ``K`` are the identity's and their basis rows zero, so the kept points'
    factor, trend and weights are those of their own arrays (to round-off). Also returns
    whether ``K`` factorised."""
    k = matern32(xs, xs, ell, s2)
    both = keep[:, None] * keep[None, :]
    chol = jnp.linalg.cholesky(k * both + jnp.diag(nug * keep + (1.0 - keep)))
    h = basis(xs, mean)
    alpha, beta, w, r = _weights(chol, h * keep[:, None], ys)
    ok = jnp.all(jnp.isfinite(chol))
    k_star = k * keep[None, :]  # (n, n): each point against the kept ones
    v = jax.scipy.linalg.solve_triangular(chol, k_star.T, lower=True)
    mean_s = k_star @ alpha
    var_s = s2 - jnp.sum(v * v, axis=0)
    if h.shape[1]:
        mean_s = mean_s + h @ beta
        q = jax.scipy.linalg.solve_triangular(r, h.T - w.T @ v, lower=True)
        var_s = var_s + jnp.sum(q * q, axis=0)
    return mean_s, jnp.maximum(var_s, 0.0) + nug, ok & jnp.all(jnp.isfinite(alpha))


def condition(
    x: np.ndarray,
    y: np.ndarray,
    *,
    lower: np.ndarray,
    upper: np.ndarray,
    lengthscales: np.ndarray,
    signal_var: float,
    nugget: float,
    transform: str | None = None,
    name: str = "",
    nlml: float = float("nan"),
    mean: str = "constant",
) -> FittedGP:
    """Condition a GP with *given* hyperparameters on training data (no optimisation).

    Inputs are not validated here; :func:`calnet.surrogates.fit_gp` does that.

    Parameters
    ----------
    x : array, shape (n, d)
        Training inputs, physical units.
    y : array, shape (n,)
        Training outputs, natural scale (``log`` is applied when ``transform="log"``).
    lower, upper : array, shape (d,)
        Input bounds, physical units.
    lengthscales : array, shape (d,)
        Length scales in unit-cube units.
    signal_var, nugget : float
        Variances in standardised-output units.
    transform : {None, "log"}
    name : str
    nlml : float
        Recorded as the attribute of the same name.
    mean : {"constant", "linear", "quadratic"}, default "constant"
        Mean function (module docstring); a trend's coefficients are the generalised
        least-squares estimate at these hyperparameters.

    Returns
    -------
    FittedGP
        Its ``chol`` is NaN if ``K`` is not numerically positive definite; check with
        ``jnp.isfinite(gp.chol[-1, -1])``.
    """
    f64 = partial(jnp.asarray, dtype=jnp.float64)
    lower, upper, ell, s2, nug = (f64(v) for v in (lower, upper, lengthscales, signal_var, nugget))
    xs, alpha, chol, y_mean, y_std, beta, w, r = _condition_arrays(
        f64(x), f64(y), lower, upper, ell, s2, nug, transform == "log", mean)
    return FittedGP(x_train=xs, alpha=alpha, chol=chol, lengthscales=ell, signal_var=s2,
                    nugget=nug, lower=lower, upper=upper, y_mean=y_mean, y_std=y_std,
                    nlml=f64(nlml), beta=beta, basis_solve=w, basis_chol=r,
                    transform=transform, name=name)
