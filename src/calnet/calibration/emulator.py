"""Surrogate mean (and variance) at fixed experimental inputs, as KOH ``mean_fn``.

During a calibration the control inputs of the experiments are fixed and only ``theta``
moves, so the control-input part of every kernel distance is computed once:

    d2(z_i, Z_j) = sum_x ((x_i - X_j) / l_x)^2  +  sum_t ((theta - T_j) / l_t)^2
                   \\_______ (n, N), once ______/    \\______ (N,), per evaluation ______/

which turns the (n, N, d) distance computation of each log-density evaluation into an
(N, p) one (koh_anchor README). The GP is a Matern-3/2 ARD posterior mean
``mu0 + amp * k32(z, Z) @ alpha`` (method.md section 2), with the weights
``c = amp * alpha`` (times the output scale if the GP was fitted on standardised outputs
and the mean is wanted on another scale).

:func:`fixed_input_gp` returns ``(mean_fn, mean_args)`` for
:func:`calnet.calibration.koh.build_logdensity`; ``mean_fn`` is a module-level function,
so calibrations of the same shapes share one compiled sampler.
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from calnet.errors import CalibrationError  # noqa: E402

__all__ = ["fixed_input_gp", "matern32_mean", "matern32_var", "matern32_of_d2"]

EPS_R2 = 1e-12  # added to the squared distance under the square root (finite gradient at 0)


@jax.custom_jvp
def matern32_of_d2(d2):
    """Matern-3/2 correlation ``(1 + r) exp(-r)``, ``r = sqrt(3 d2)``, of squared distances."""
    r = jnp.sqrt(3.0 * (d2 + EPS_R2))
    return (1.0 + r) * jnp.exp(-r)


@matern32_of_d2.defjvp
def _matern32_jvp(primals, tangents):
    # d/d(d2) [(1 + r) e^-r] = -r e^-r * dr/d(d2) = -1.5 e^-r: no square root in the tangent
    (d2,), (t,) = primals, tangents
    r = jnp.sqrt(3.0 * (d2 + EPS_R2))
    e = jnp.exp(-r)
    return (1.0 + r) * e, -1.5 * e * t


def _correlation(theta, args):
    d2t = jnp.sum((theta * args["theta_scale"] - args["theta_train"]) ** 2, axis=-1)  # (N,)
    return matern32_of_d2(args["d2x"] + d2t)  # (n, N)


def matern32_mean(theta, args):
    """GP mean at the fixed inputs for parameters ``theta`` (p,) -> (n,)."""
    return args["mu0"] + _correlation(theta, args) @ args["c"]


def matern32_var(theta, args):
    """GP predictive variance at the fixed inputs (n,), floored at 0; needs ``k_inv``."""
    k = _correlation(theta, args)
    amp = args["amp"]
    var = amp - amp**2 * jnp.sum((k @ args["k_inv"]) * k, axis=-1)  # amp - k*^T K^-1 k*
    return args["var_scale"] * jnp.maximum(var, 0.0)


def fixed_input_gp(x_exp, X_train, lengthscales, c, mu0, *, theta_shift=None,
                   theta_scale=None, amp=None, k_inv=None, var_scale=1.0):
    """``(mean_fn, mean_args)`` of a Matern-3/2 ARD GP whose inputs are ``[x, theta]``.

    Parameters
    ----------
    x_exp : array, (n, q)
        Control inputs of the experiments, on the GP's input scale.
    X_train : array, (N, q + p)
        GP training inputs, control inputs first.
    lengthscales : array, (q + p,)
        ARD length scales.
    c : array, (N,)
        Weights of the mean, ``amp * K^-1 y`` on the output scale wanted.
    mu0 : float
        Constant mean.
    theta_shift, theta_scale : array (p,), optional
        Affine map from the sampled ``theta`` to the GP's input scale,
        ``(theta - shift) / scale`` (e.g. the bounds, for a unit-cube GP).
    amp, k_inv : optional
        Signal variance and ``K^-1`` (N, N) of the training covariance (noise included),
        for :func:`matern32_var`; ``var_scale`` multiplies the variance (output scale^2).

    Returns
    -------
    mean_fn : callable ``(theta, mean_args) -> (n,)``
    mean_args : dict of arrays
    """
    x = np.atleast_2d(np.asarray(x_exp, dtype=float))
    Z = np.asarray(X_train, dtype=float)
    ls = np.asarray(lengthscales, dtype=float)
    q = x.shape[1]
    p = Z.shape[1] - q
    if p < 1 or ls.shape != (Z.shape[1],) or np.shape(c) != (Z.shape[0],):
        raise CalibrationError(
            f"fixed_input_gp: expected X_train (N, q + p) with p >= 1, lengthscales "
            f"({Z.shape[1]},) and c ({Z.shape[0]},); got x_exp {x.shape}, X_train {Z.shape}, "
            f"lengthscales {ls.shape}, c {np.shape(c)}")
    shift = np.zeros(p) if theta_shift is None else np.asarray(theta_shift, dtype=float)
    scale = np.ones(p) if theta_scale is None else np.asarray(theta_scale, dtype=float)
    a = 1.0 / (scale * ls[q:])
    d2x = np.sum(((x[:, None, :] - Z[None, :, :q]) / ls[:q]) ** 2, axis=-1)  # (n, N) once
    args = {"d2x": jnp.asarray(d2x), "theta_scale": jnp.asarray(a),
            "theta_train": jnp.asarray(shift * a + Z[:, q:] / ls[q:]),
            "c": jnp.asarray(c, dtype=float), "mu0": jnp.asarray(float(mu0))}
    if k_inv is not None:
        if amp is None:
            raise CalibrationError("fixed_input_gp: k_inv given without amp")
        args.update(amp=jnp.asarray(float(amp)), k_inv=jnp.asarray(k_inv, dtype=float),
                    var_scale=jnp.asarray(float(var_scale)))
    return matern32_mean, args
