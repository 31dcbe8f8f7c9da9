"""The Kennedy-O'Hagan model of a network: one object for calibration and prediction.

method.md sections 3-5. Each data set ``d`` observing output ``y`` of model ``m`` is a
*term*

    y_d = yhat_m(x_m; theta_m) + delta_d(x_m) + eps_d,

where ``x_m`` are the model's control inputs at the experimental process settings (free
inputs read from the data, linked inputs produced by the upstream surrogates),
``yhat_m`` the GP surrogate mean, ``delta_d ~ GP(0, sd2 k_SE(.; ell))`` the discrepancy on
the unit cube of the model's inputs (optional) and ``eps_d ~ N(0, se2)`` the noise, sampled
or known per point. With the discrepancy integrated out,

    y_d ~ MVN(yhat, C_delta + diag(noise + surrogate variance)).

The surrogate variance is the observed output's GP variance plus, to first order, the
variance that each upstream (linked) surrogate passes down the chain.

*Orthogonal discrepancy* (the default): ``delta_d`` is conditioned on having no component
along the directions in which the parameters sampled with the data set move the surrogate
at the data (``G = d yhat / d theta``, ``G^T delta(X) = 0``; the observed model's own and,
through the links, those of the models upstream: :attr:`Term.directions`), so that the
discrepancy cannot mimic a change of parameters (Plumlee 2017; Brynjarsdottir and O'Hagan
2014). A correct model then gets the parameter posterior it would get without a
discrepancy.

Every variable is in the data's own units on the modelled scale (``ln y`` for an output
with ``transform: log``): variances ``sd2`` and ``se2`` in (unit)^2, length scales on the
unit cube. The log-density is the density of the observations in those units; inside,
outputs are standardised for numerical stability only.

:class:`KOHModel` is the static, hashable part (the key of compiled samplers); ``data``
is a pytree of arrays. ``KOHModel.logdensity(data, u)`` and ``KOHModel.predict(...)``
are pure JAX functions. :class:`KOHDensity` binds both for the sampler.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from calnet.calibration.priors import (
    LogNormal,
    Prior,
    init_from_priors,
    stack_priors,
)
from calnet.chain import ChainPlan
from calnet.errors import CalibrationError

__all__ = ["Term", "KOHModel", "KOHDensity", "se_kernel", "mvn_logpdf_chol", "check_initial",
           "initial_point_message", "standardise", "HYPERPARAMETERS"]

HYPERPARAMETERS = ("ell", "sd2", "se2")
_LOG_2PI = math.log(2.0 * math.pi)
JITTER = 1e-10  # added to the diagonal of standardised covariances
_STAND_IN = LogNormal(0.0, 1.0)  # see Term.without_priors


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


def se_kernel(xa, xb, ell):
    """Squared-exponential correlation ``exp(-0.5 sum_d (xa_d - xb_d)^2 / ell_d^2)``, (na, nb)."""
    d2 = (xa[:, None, :] - xb[None, :, :]) ** 2
    return jnp.exp(-0.5 * jnp.sum(d2 / ell**2, axis=-1))


def standardise(y: np.ndarray) -> tuple[float, float]:
    """Mean and sd used to standardise observations (sd 1 for a single point)."""
    sd = float(np.std(y)) if len(y) > 1 else 1.0
    return float(np.mean(y)), (sd if sd > 0 and math.isfinite(sd) else 1.0)


@dataclass(frozen=True)
class Term:
    """Static part of one data set's KOH term.

    Attributes
    ----------
    name, model, key : str
        Data set, observed model and ``model.output`` of the observed surrogate.
    ell_priors : tuple of Prior
        Discrepancy length scales, one per control input (empty without discrepancy).
    sd2_prior : Prior or None
        Discrepancy variance (data units^2); None: no discrepancy.
    se2_prior : Prior or None
        Noise variance (data units^2); None: the noise is known (``noise_var`` in data).
    orthogonal : bool
        Discrepancy orthogonal to the model's parameter directions at the data.
    emulator_variance : bool
        Add the surrogate variances (observed output and, to first order, linked ones).
    links : tuple of str
        ``model.output`` of the surrogates feeding the observed model's inputs, directly
        or further up the chain (their variance is propagated when emulator_variance).
    directions : tuple of str
        The models whose parameters the orthogonal discrepancy is orthogonal to: those
        whose parameters are sampled with this data set, the observed model and the
        models upstream of it (empty: the observed model alone).
    """

    name: str
    model: str
    key: str
    ell_priors: tuple[Prior, ...]
    sd2_prior: Prior | None
    se2_prior: Prior | None
    orthogonal: bool = True
    emulator_variance: bool = True
    links: tuple[str, ...] = ()
    directions: tuple[str, ...] = ()

    @property
    def discrepancy(self) -> bool:
        return self.sd2_prior is not None

    @property
    def noise_known(self) -> bool:
        return self.se2_prior is None

    def without_priors(self) -> Term:
        """This term with its priors replaced by one fixed stand-in (prediction and the
        checks after calibration use no prior), so that terms of the same structure share
        one compiled program whatever data set their default priors were scaled on."""
        stand_in = _STAND_IN
        return replace(self, ell_priors=(stand_in,) * len(self.ell_priors),
                       sd2_prior=None if self.sd2_prior is None else stand_in,
                       se2_prior=None if self.se2_prior is None else stand_in)

    def blocks(self) -> list[tuple[str, tuple[Prior, ...]]]:
        """(variable, priors) of this term's sampled hyperparameters, in ``u`` order."""
        out = []
        if self.discrepancy:
            out += [(f"ell_{self.name}", self.ell_priors), (f"sd2_{self.name}", (self.sd2_prior,))]
        if not self.noise_known:
            out.append((f"se2_{self.name}", (self.se2_prior,)))
        return out


@dataclass(frozen=True)
class KOHModel:
    """Hashable description of a network's KOH log-density and predictive.

    Attributes
    ----------
    plan : ChainPlan
        The network's data flow.
    params : tuple of (key, Prior)
        The sampled calibration parameters: ``model.parameter``, or the bare name of a
        shared parameter.
    theta_index : tuple of (model, tuple of int)
        For every model, the position in ``params`` of each of its parameters, or -1 for
        a parameter held fixed (its value comes from ``data["theta_fixed"][model]``).
    groups : tuple of (variable, tuple of int)
        Posterior variables of the parameters (``theta_<model>``, ``theta_shared``) and
        the positions in ``params`` they hold.
    terms : tuple of Term
    """

    plan: ChainPlan
    params: tuple[tuple[str, Prior], ...]
    theta_index: tuple[tuple[str, tuple[int, ...]], ...]
    groups: tuple[tuple[str, tuple[int, ...]], ...]
    terms: tuple[Term, ...]

    # ------------------------------------------------------------ layout of u
    def blocks(self) -> list[tuple[str, tuple[Prior, ...]]]:
        """(name, priors) of the blocks of the unconstrained vector ``u``, in order."""
        out = [("params", tuple(p for _, p in self.params))] if self.params else []
        for t in self.terms:
            out += t.blocks()
        return out

    @property
    def dim(self) -> int:
        return sum(len(priors) for _, priors in self.blocks())

    def unpack(self, u):
        """Constrained values of every block of ``u`` and the summed log prior (with the
        log-Jacobian of each bijection)."""
        blocks = self.blocks()
        priors = [p for _, block in blocks for p in block]
        xs, lp = [], 0.0
        for start, stop, stacked in stack_priors(priors):  # vectorised runs of one class
            xs.append(stacked.to_constrained(u[start:stop]))
            lp = lp + jnp.sum(stacked.log_prob_unconstrained(u[start:stop]))
        x = jnp.concatenate(xs) if len(xs) > 1 else xs[0]
        out, i = {}, 0
        for name, block in blocks:
            vals = x[i:i + len(block)]
            out[name] = vals if name == "params" or name.startswith("ell_") else vals[0]
            i += len(block)
        out.setdefault("params", jnp.zeros(0))
        return out, lp

    def thetas(self, data, params) -> dict:
        """Parameter vector of every model, (p_m,) each: sampled or fixed."""
        out = {}
        for model, idx in self.theta_index:
            idx_a = np.asarray(idx, dtype=int)
            fixed = data["theta_fixed"][model]
            if not len(idx_a) or np.all(idx_a < 0):
                out[model] = fixed
            elif np.all(np.diff(idx_a) == 1) and idx_a[0] >= 0:  # a run of params: a slice
                out[model] = params[idx_a[0]:idx_a[-1] + 1]
            else:
                take = params[np.clip(idx_a, 0, None)]
                out[model] = jnp.where(jnp.asarray(idx_a >= 0), take, fixed)
        return out

    @staticmethod
    def hyper(term: Term, tdata, values) -> dict:
        """``ell``, ``sd2``, ``se2`` of a term (data units; zeros where absent)."""
        q = len(term.ell_priors)
        return {"ell": values.get(f"ell_{term.name}", jnp.ones(q)),
                "sd2": values.get(f"sd2_{term.name}", 0.0),
                "se2": values.get(f"se2_{term.name}", 0.0)}

    # ------------------------------------------------------------ one term
    def inputs(self, data, term: Term, xp, thetas, eps=None):
        """Control inputs (n, q) of the term's model; with emulator variance and linked
        surrogates also, per link, the inputs' first-order response to one standard
        deviation of that surrogate at each point (K, n, q) and the surrogate's
        correlation across the points (K, n, n) (K = len(term.links)); else None, None."""
        gps = data["gps"]

        def x_of(e):
            return self.plan.inputs(gps, term.model, xp, thetas, e)

        e0 = {k: jnp.zeros(next(iter(xp.values())).shape[0]) for k in term.links}
        base = {**e0, **(eps or {})}
        x = x_of(base)
        if not (term.emulator_variance and term.links):
            return x, None, None
        dx, corr = [], []
        for k in term.links:
            tangent = {kk: (jnp.ones_like(v) if kk == k else jnp.zeros_like(v))
                       for kk, v in base.items()}
            dx.append(jax.jvp(x_of, (base,), (tangent,))[1])
            src = k.split(".")[0]
            x_src = self.plan.inputs(gps, src, xp, thetas, base)
            cov = self.plan.predict_cov(gps, src, k, x_src, thetas[src])[1]
            sd = jnp.sqrt(jnp.maximum(jnp.diag(cov), 0.0) + 1e-30)
            corr.append(cov / jnp.outer(sd, sd))
        return x, jnp.stack(dx), jnp.stack(corr)

    def _moments(self, data, term: Term, x, dx, corr, theta, at=None):
        """Surrogate mean (n,) of the observed output at inputs ``x`` and the surrogates'
        covariance across the points (n, n): the observed output's GP covariance plus, to
        first order, each linked surrogate's (None without emulator variance)."""
        gps = data["gps"]

        def mean_at(xx):
            return self.plan.predict(gps, term.model, term.key, xx, theta)[0]

        if at is not None:  # fixed inputs: only the parameter part of the distances
            mean, cov = self.plan.moments_at(gps, term.model, term.key, at, theta,
                                             cov=term.emulator_variance)
        elif not term.emulator_variance:
            return mean_at(x), None
        else:
            mean, cov = self.plan.predict_cov(gps, term.model, term.key, x, theta)
        if not term.emulator_variance:
            return mean, None
        if dx is not None:
            for k in range(dx.shape[0]):
                d = jax.jvp(mean_at, (x,), (dx[k],))[1]
                cov = cov + corr[k] * jnp.outer(d, d)
        return mean, cov

    def _directions(self, data, term: Term, tdata, x, thetas, s):
        """``d yhat / d theta`` at the data, standardised, (n, p): one column per parameter
        of each model of ``term.directions`` (the observed model's own, and those of the
        models upstream whose parameters act on it through the linked inputs); None
        without an orthogonal discrepancy or without such parameters. A parameter shared
        by two of those models has a column in each (the discrepancy is orthogonal to
        either model's response to it)."""
        if not (term.orthogonal and term.discrepancy):
            return None
        models = [m for m in (term.directions or (term.model,)) if thetas[m].shape[0]]
        if not models:
            return None
        gps = data["gps"]
        linked = "x_fixed" not in tdata and any(m != term.model for m in models)

        def mean(sub):
            th = {**thetas, **sub}
            xx = self.plan.inputs(gps, term.model, tdata["xp"], th) if linked else x
            return self.plan.predict_mean(gps, term.model, term.key, xx, th[term.model])

        jac = jax.jacfwd(mean)({m: thetas[m] for m in models})
        return jnp.concatenate([jac[m] for m in models], axis=1) / s

    def train(self, data, term: Term, tdata, thetas, hyper):
        """Standardised residual (n,), covariance (n, n) (or its diagonal (n,) when it is
        diagonal: no discrepancy, no emulator variance), and what prediction needs (unit
        inputs, parameter directions)."""
        at = None
        if "x_fixed" in tdata:  # inputs precomputed: no sampled parameter upstream
            x, dx, corr = tdata["x_fixed"], tdata.get("dx_fixed"), tdata.get("corr_fixed")
            at = tdata["gp_fixed"]
        else:
            x, dx, corr = self.inputs(data, term, tdata["xp"], thetas)
        theta = thetas[term.model]
        s = tdata["y_sd"]
        mean, cov = self._moments(data, term, x, dx, corr, theta, at)
        r = tdata["y"] - (mean - tdata["y_mean"]) / s
        noise = tdata["noise_var"] if term.noise_known else hyper["se2"]
        diag = noise / s**2 * jnp.ones_like(r) + JITTER
        if not term.discrepancy and cov is None:
            return r, diag, None
        K = jnp.diag(diag) if cov is None else cov / s**2 + jnp.diag(diag)
        if not term.discrepancy:
            return r, K, None
        u = self.plan.unit_inputs(term.model, x)
        d2 = tdata["d2u_fixed"] if "d2u_fixed" in tdata else (u[:, None, :] - u[None]) ** 2
        C = hyper["sd2"] / s**2 * jnp.exp(-0.5 * jnp.sum(d2 / hyper["ell"] ** 2, axis=-1))
        G = self._directions(data, term, tdata, x, thetas, s)
        proj = None
        if G is not None:
            A = C @ G
            M = G.T @ A
            M = M + (1e-9 * jnp.trace(M) / M.shape[0] + 1e-300) * jnp.eye(M.shape[0])
            C = C - A @ jnp.linalg.solve(M, A.T)
            proj = (G, M, A)
        return r, C + K, {"u": u, "proj": proj}

    def term_loglik(self, data, term: Term, tdata, thetas, hyper):
        """Log-likelihood of one data set, in its units on the modelled scale."""
        r, K, _ = self.train(data, term, tdata, thetas, hyper)
        n = r.shape[0]
        if K.ndim == 1:
            ll = -0.5 * jnp.sum(r**2 / K + jnp.log(K)) - 0.5 * n * _LOG_2PI
        else:
            ll = mvn_logpdf_chol(r, K)
        return ll - n * jnp.log(tdata["y_sd"])

    def term_predict(self, data, term: Term, tdata, thetas, hyper, xp_new, eps, noise_new):
        """KOH predictive at new process settings for one posterior draw.

        Returns standardised mean (m,) and the variance parts (m,) each: discrepancy,
        observed surrogate, noise. ``eps`` perturbs linked surrogates (model.output ->
        (m,) standard normals) to propagate their uncertainty by sampling; ``noise_new``
        (m,) is the known noise variance at the new points (data units).
        """
        s = tdata["y_sd"]
        r, K, extra = self.train(data, term, tdata, thetas, hyper)
        theta = thetas[term.model]
        x_p = self.plan.inputs(data["gps"], term.model, xp_new, thetas, eps)
        m_p, v_p = self.plan.predict(data["gps"], term.model, term.key, x_p, theta)
        mean = (m_p - tdata["y_mean"]) / s
        noise = (noise_new if term.noise_known else hyper["se2"] * jnp.ones_like(mean)) / s**2
        v_emu = v_p / s**2 if term.emulator_variance else jnp.zeros_like(mean)
        if not term.discrepancy:
            return mean, jnp.zeros_like(mean), v_emu, noise
        sd2 = hyper["sd2"] / s**2
        up = self.plan.unit_inputs(term.model, x_p)
        kpe = sd2 * se_kernel(up, extra["u"], hyper["ell"])  # (m, n)
        prior_var = sd2 * jnp.ones_like(mean)
        if extra["proj"] is not None:  # condition on G^T delta(X) = 0
            G, M, A = extra["proj"]  # A = C(X, X) G, from train
            B = kpe @ G  # (m, p)
            kpe = kpe - B @ jnp.linalg.solve(M, A.T)
            prior_var = prior_var - jnp.sum(B * jnp.linalg.solve(M, B.T).T, axis=1)
        L = jnp.linalg.cholesky(K)
        mean = mean + kpe @ jsl.cho_solve((L, True), r)
        a = jsl.solve_triangular(L, kpe.T, lower=True)
        var_delta = jnp.maximum(prior_var - jnp.sum(a * a, axis=0), 0.0)
        return mean, var_delta, v_emu, noise

    # ------------------------------------------------------------ whole network
    def _terms_loglik(self, data, values):
        """Summed log-likelihood of every data set at constrained ``values``."""
        thetas = self.thetas(data, values["params"])
        total = 0.0
        for term, tdata in zip(self.terms, data["terms"], strict=True):
            total = total + self.term_loglik(data, term, tdata, thetas,
                                             self.hyper(term, tdata, values))
        return total

    def loglik(self, data, u):
        """Log-likelihood of every data set at ``u`` (dim,)."""
        return self._terms_loglik(data, self.unpack(u)[0])

    def logdensity(self, data, u):
        """Unnormalised log posterior density of ``u`` (dim,); ``-inf`` where non-finite."""
        values, lp = self.unpack(u)
        return finite_or_neg_inf(lp + self._terms_loglik(data, values))

    def constrain(self, data, u):
        """Posterior variables from ``u``: ``theta_<model>`` / ``theta_shared`` and each
        term's ``ell_``, ``sd2_``, ``se2_`` (data units)."""
        values, _ = self.unpack(u)
        out = {name: values["params"][np.asarray(idx, dtype=int)] for name, idx in self.groups}
        out.update({k: v for k, v in values.items() if k != "params"})
        return out

    def init(self, seed, n_chains: int):
        """Prior draws on the unconstrained scale, (n_chains, dim); seed: int or Generator."""
        return init_from_priors(self.blocks(), seed, n_chains)


@dataclass(frozen=True)
class KOHDensity:
    """A :class:`KOHModel` bound to its data: what :func:`sample_nuts` samples.

    Attributes
    ----------
    spec : KOHModel
    data : dict
        ``gps`` (model.output -> FittedGP), ``theta_fixed`` (model -> (p_m,)), ``terms``
        (per data set: ``y`` standardised (n,), ``y_mean``, ``y_sd``, ``xp`` process
        inputs, ``noise_var`` (n,) known noise variance in data units, and
        ``x_fixed``/``dx_fixed``/``corr_fixed``/``gp_fixed``/``d2u_fixed`` where the
        inputs do not depend on sampled parameters),
        ``y`` (all standardised observations, for the InferenceData).
    name : str
    names : dict of variable -> coordinate names (parameters, discrepancy inputs)
    param_keys : dict of model -> keys of its parameters (``model.name``, or the bare
        name of a shared parameter), in declared order
    """

    spec: KOHModel
    data: dict = field(repr=False)
    name: str
    names: Mapping[str, tuple[str, ...]]
    param_keys: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    @property
    def dim(self) -> int:
        return self.spec.dim

    @property
    def sampled_vars(self) -> tuple[str, ...]:
        return (tuple(name for name, _ in self.spec.groups)
                + tuple(name for name, _ in self.spec.blocks() if name != "params"))

    @property
    def dims(self) -> dict[str, list[str]]:
        return {v: [f"{v}_dim"] for v in self.names}

    @property
    def coords(self) -> dict[str, list[str]]:
        return {f"{v}_dim": list(c) for v, c in self.names.items()}

    def logdensity(self, u):
        return self.spec.logdensity(self.data, u)

    def loglik(self, u):
        return self.spec.loglik(self.data, u)

    def constrain(self, u):
        return self.spec.constrain(self.data, u)

    def init(self, seed, n_chains: int):
        return self.spec.init(seed, n_chains)


def _value_and_grad(spec, data, u):
    return jax.vmap(jax.value_and_grad(spec.logdensity, argnums=1), in_axes=(None, 0))(data, u)


_value_and_grad_jit = jax.jit(_value_and_grad, static_argnums=0)


def check_initial(ld, u0, model_name: str | None = None) -> None:
    """Raise :class:`~calnet.errors.CalibrationError` if the log-density or its gradient is
    non-finite at any initial point ``u0`` (n_chains, dim)."""
    name = model_name or getattr(ld, "name", "model")
    u0 = jnp.atleast_2d(jnp.asarray(u0, dtype=float))
    values, grads = _value_and_grad_jit(ld.spec, ld.data, u0)
    values, grads = np.asarray(values), np.asarray(grads)
    bad = ~np.isfinite(values) | ~np.all(np.isfinite(grads), axis=1)
    if bad.any():
        raise CalibrationError(initial_point_message(name, values, bad))


def initial_point_message(name: str, values: np.ndarray, bad: np.ndarray) -> str:
    """The error for initial points (chains ``bad``, (n_chains,) bool) where the
    log-density (``values`` (n_chains,)) or its gradient is not finite."""
    values = np.asarray(values, dtype=float)
    what = ("log-density" if (~np.isfinite(values[bad])).any()
            else "gradient of the log-density")
    return (f"{name}: the {what} is not finite at the initial point(s) of chain(s) "
            f"{np.flatnonzero(bad).tolist()} (values {values.tolist()}); check that the "
            "surrogate mean is finite for parameters inside their bounds and that the data "
            "are finite")
