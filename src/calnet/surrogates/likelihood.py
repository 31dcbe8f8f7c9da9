"""Log marginal likelihood of a Matern 3/2 ARD GP with a nugget, and its gradient.

Hyperparameters travel as one unconstrained vector ``log_params`` of length ``d + 2``::

    log_params = [log ell_1, ..., log ell_d, log s2, log nugget]

with length scales in unit-cube units and both variances in standardised-output units.
Everything here is a pure JAX function; a numerical failure (a Cholesky factor with NaN)
gives ``+inf`` for the negative log likelihood instead of an exception, so that inside
jitted code an optimizer or sampler rejects the step rather than stopping.

A mean function ``h(x)^T beta`` with basis ``H`` (n, p) (:func:`basis`) is integrated out
under a flat prior on ``beta``: the likelihood is then the restricted (REML) one,
``0.5 y^T P y + 0.5 log|K| + 0.5 log|H^T K^-1 H| + 0.5 (n - p) log(2 pi)`` with
``P = K^-1 - K^-1 H (H^T K^-1 H)^-1 H^T K^-1`` (Rasmussen and Williams 2006, section 2.7;
Harville 1977), and its gradient the same closed form as without a mean function with
``P`` in place of ``K^-1`` and ``P y`` in place of ``alpha``. With ``p = 0`` (no column:
the outputs' standardisation is the mean) both are the plain marginal likelihood's.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import cho_solve, solve_triangular

from calnet.surrogates.kernels import SQRT3, scaled_sqdist

LOG_2PI = math.log(2.0 * math.pi)


def unpack(log_params: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Split ``log_params`` (d + 2,) into length scales (d,), signal variance, nugget."""
    p = jnp.exp(log_params)
    return p[:-2], p[-2], p[-1]


MEANS = ("constant", "linear", "quadratic")


def n_basis(mean: str, d: int) -> int:
    """Columns of :func:`basis` for ``d`` inputs."""
    return {"constant": 0, "linear": d + 1, "quadratic": (d + 1) * (d + 2) // 2}[mean]


def trend_runs(mean: str, d: int) -> int:
    """Runs a fit with mean function ``mean`` in ``d`` inputs needs beyond the kernel's
    own: the trend's coefficients and two more (0 coefficients for a constant mean)."""
    return n_basis(mean, d) + 2


def mean_of(p: int, d: int) -> str:
    """The mean function whose basis has ``p`` columns for ``d`` inputs."""
    for mean in MEANS:
        if n_basis(mean, d) == p:
            return mean
    raise ValueError(f"no mean function has {p} basis columns for {d} inputs")


def basis(x: jax.Array, mean: str) -> jax.Array:
    """Basis ``H`` (n, p) of the mean function at unit-cube inputs ``x`` (n, d): no column
    for ``"constant"`` (the standardised outputs' zero mean), ``[1, x]`` for ``"linear"``,
    and ``[1, x, x_i x_j (i <= j)]`` for ``"quadratic"`` (the products centred on the
    cube's middle, for conditioning)."""
    if mean == "constant":
        return jnp.zeros((x.shape[0], 0), dtype=x.dtype)
    cols = [jnp.ones((x.shape[0], 1), dtype=x.dtype), x]
    if mean == "quadratic":
        c = x - 0.5
        i, j = np.triu_indices(x.shape[1])
        cols.append(c[:, i] * c[:, j])
    elif mean != "linear":
        raise ValueError(f"mean must be one of {MEANS}, got {mean!r}")
    return jnp.concatenate(cols, axis=1)


def _restricted(chol, alpha, H):
    """``(P y, log|H^T K^-1 H|^(1/2), K^-1 H, cholesky(H^T K^-1 H))`` for the REML terms."""
    k_inv_h = cho_solve((chol, True), H)
    r = jnp.linalg.cholesky(H.T @ k_inv_h)
    beta = cho_solve((r, True), H.T @ alpha)
    return alpha - k_inv_h @ beta, jnp.sum(jnp.log(jnp.diag(r))), k_inv_h, r


def _factor(log_params, x, y, mask=None):
    """Shared pieces: Cholesky factor, alpha, exp(-sqrt3 r), noise-free K, hyperparameters.

    With ``mask`` (n,) of ones and zeros, the points of mask 0 are decoupled: their rows
    and columns of ``K`` are those of the identity (``e`` and ``K_f`` zero there), so
    that with ``y`` zero there they add nothing but constants (:func:`nlml_value_and_grad`).
    """
    ell, s2, nugget = unpack(log_params)
    r2 = scaled_sqdist(x, x, ell)
    positive = r2 > 0.0
    sr = SQRT3 * jnp.where(positive, jnp.sqrt(jnp.where(positive, r2, 1.0)), 0.0)
    e = jnp.exp(-sr)
    if mask is not None:
        e = e * (mask[:, None] * mask[None, :])
    k_free = s2 * (1.0 + sr) * e
    diag = nugget if mask is None else nugget * mask + (1.0 - mask)
    chol = jnp.linalg.cholesky(k_free + diag * jnp.eye(x.shape[0], dtype=x.dtype))
    alpha = cho_solve((chol, True), y)
    return chol, alpha, e, k_free, s2, nugget, ell


def _value(chol, alpha, y, log_det_a=0.0, p: int = 0, n=None):
    # Rasmussen and Williams (2006) eq. (2.30), sign flipped; REML with p basis columns
    n = y.shape[0] if n is None else n
    val = (0.5 * jnp.dot(y, alpha) + jnp.sum(jnp.log(jnp.diag(chol))) + log_det_a
           + 0.5 * (n - p) * LOG_2PI)
    return jnp.where(jnp.isfinite(val), val, jnp.inf)


def neg_log_marginal_likelihood(log_params: jax.Array, x: jax.Array, y: jax.Array,
                                H: jax.Array | None = None) -> jax.Array:
    """Negative log marginal likelihood of standardised outputs.

    Parameters
    ----------
    log_params : array, shape (d + 2,)
        ``[log ell (d), log s2, log nugget]``.
    x : array, shape (n, d)
        Training inputs scaled to the unit cube.
    y : array, shape (n,)
        Standardised training outputs (zero mean, unit variance).
    H : array, shape (n, p), optional
        Basis of the mean function (:func:`basis`); none: zero mean.

    Returns
    -------
    scalar array
        ``0.5 y^T K^-1 y + 0.5 log|K| + 0.5 n log(2 pi)`` (the restricted likelihood of the
        module docstring with a basis); ``+inf`` when ``K`` is not numerically positive
        definite.
    """
    chol, alpha, *_ = _factor(log_params, x, y)
    if H is None or H.shape[1] == 0:
        return _value(chol, alpha, y)
    py, log_det_a, *_ = _restricted(chol, alpha, H)
    return _value(chol, py, y, log_det_a, H.shape[1])


def nlml_value_and_grad(
    log_params: jax.Array, x: jax.Array, y: jax.Array, H: jax.Array | None = None,
    mask: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Negative log marginal likelihood and its gradient with respect to ``log_params``.

    The gradient is the closed form ``-0.5 tr((alpha alpha^T - K^-1) dK/dp)``
    (Rasmussen and Williams 2006, eq. 5.9), which costs one extra ``K^-1`` instead of
    reverse-mode differentiation through the Cholesky factorisation. For Matern 3/2,
    ``dk/d(r^2) = -1.5 s2 exp(-sqrt3 r)``, so
    ``dK_ij/d log ell_k = 3 s2 exp(-sqrt3 r_ij) (x_ik - x_jk)^2 / ell_k^2``.

    Parameters
    ----------
    log_params : array, shape (d + 2,)
    x : array, shape (n, d)
    y : array, shape (n,)
    H : array, shape (n, p), optional
        Basis of the mean function: the restricted likelihood, ``P`` for ``K^-1``.
    mask : array, shape (n,), optional
        Ones and zeros: the likelihood of the points of mask 1 alone, in arrays of the
        full shape (the folds of a cross-validation then run one compiled program). The
        points of mask 0 must have ``y`` and ``H``'s row zero; value and gradient equal
        those of the kept points' arrays to round-off.

    Returns
    -------
    value : scalar array
    grad : array, shape (d + 2,)
        NaN entries are replaced by zero when ``value`` is ``+inf``.
    """
    chol, alpha, e, k_free, s2, nugget, ell = _factor(log_params, x, y, mask)
    n = y.shape[0]
    k_inv = cho_solve((chol, True), jnp.eye(n, dtype=x.dtype))
    log_det_a, p = 0.0, 0
    if H is not None and H.shape[1]:  # REML: P y and P for alpha and K^-1
        p = H.shape[1]
        alpha, log_det_a, k_inv_h, r = _restricted(chol, alpha, H)
        c = solve_triangular(r, k_inv_h.T, lower=True)  # (p, n)
        k_inv = k_inv - c.T @ c
    w = jnp.outer(alpha, alpha) - k_inv  # W = alpha alpha^T - K^-1
    g_s2 = -0.5 * jnp.sum(w * k_free)  # dK/d log s2 = K_f
    w_diag = jnp.diag(w) if mask is None else jnp.diag(w) * mask
    g_nug = -0.5 * nugget * jnp.sum(w_diag)  # dK/d log nugget = nugget I (kept points)
    m = w * e
    rows = jnp.sum(m, axis=1)
    # sum_ij M_ij (x_ik - x_jk)^2 = 2 rows @ x^2 - 2 sum_k x_k^T M x_k   (M symmetric)
    quad = 2.0 * (rows @ (x * x)) - 2.0 * jnp.sum(x * (m @ x), axis=0)
    g_ell = -1.5 * s2 * quad / (ell * ell)
    grad = jnp.concatenate([g_ell, jnp.stack([g_s2, g_nug])])
    val = _value(chol, alpha, y, log_det_a, p, None if mask is None else jnp.sum(mask))
    grad = jnp.where(jnp.isfinite(val), grad, 0.0)
    return val, grad


def predictive_solve(chol: jax.Array, k_star: jax.Array) -> jax.Array:
    """``L^-1 K_*^T`` for predictive variances; ``k_star`` has shape (m, n)."""
    return solve_triangular(chol, k_star.T, lower=True)
