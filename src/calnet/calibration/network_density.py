"""The KOH log-density of a whole network or of one stage of a segmented calibration.

One construction serves both modes of method.md section 4:

* *joint*: every model with parameters is free, every data set contributes;
* *segmented*, stage k: model k is free, its data sets contribute, and the parameters of
  the upstream models are fixed to draws from their posteriors (one draw, the mode, for
  ``plug="mode"``; D draws for ``plug="posterior"``). With D draws the upstream
  uncertainty is propagated by moment matching: the surrogate mean is averaged over the
  draws and the covariance of the D means is added to the KOH covariance.

It follows the protocol of :mod:`calnet.calibration.koh` (``spec`` hashable with pure
``logdensity(data, u)`` and ``constrain(data, u)``), so
:func:`calnet.calibration.sampling.sample_nuts` samples it and reuses compiled programs
across calibrations of equal shapes (leave-one-out).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from calnet.calibration.koh import mvn_logpdf_chol  # noqa: E402
from calnet.calibration.priors import Prior, init_from_priors  # noqa: E402
from calnet.chain import ChainPlan  # noqa: E402


@dataclass(frozen=True)
class TermSpec:
    """Static part of one data set's KOH term."""

    name: str
    model: str
    key: str  # "model.output" of the observed output's GP
    ell_priors: tuple[Prior, ...]
    sd2_prior: Prior
    se2_prior: Prior
    emulator_variance: bool


@dataclass(frozen=True)
class NetworkKOHSpec:
    """Hashable description of a network KOH log-density (see the module docstring)."""

    plan: ChainPlan
    free: tuple[tuple[str, tuple[Prior, ...]], ...]  # (model, theta priors)
    fixed_models: tuple[str, ...]  # models whose theta comes from data["upstream"]
    terms: tuple[TermSpec, ...]

    @property
    def dim(self) -> int:
        return (sum(len(p) for _, p in self.free)
                + sum(len(t.ell_priors) + 2 for t in self.terms))

    def _blocks(self):
        blocks = [(f"theta_{m}", priors) for m, priors in self.free]
        for t in self.terms:
            blocks += [(f"ell_{t.name}", t.ell_priors), (f"sd2_{t.name}", (t.sd2_prior,)),
                       (f"se2_{t.name}", (t.se2_prior,))]
        return blocks

    def _unpack(self, u):
        out, lp, i = {}, 0.0, 0
        for name, priors in self._blocks():
            vals = []
            for prior in priors:
                vals.append(prior.to_constrained(u[i]))
                lp = lp + prior.log_prob_unconstrained(u[i])
                i += 1
            vals = jnp.stack(vals) if vals else jnp.zeros(0)
            out[name] = vals if name.startswith(("theta_", "ell_")) else vals[0]
        return out, lp

    def thetas(self, data, c) -> dict:
        """Free parameters from ``c`` plus empty vectors for parameter-less models."""
        th = {p.name: jnp.zeros(0) for p in self.plan.models if p.n_parameters == 0}
        th.update({m: c[f"theta_{m}"] for m, _ in self.free})
        return th

    def inputs_fixed(self, term: TermSpec) -> bool:
        """Whether the term's model inputs depend on no sampled parameter: its model is
        the only free one (a segmented stage), so its upstream inputs can be computed
        once per upstream draw instead of at every gradient."""
        return {m for m, _ in self.free} <= {term.model}

    def fixed_inputs(self, data, term: TermSpec, tdata):
        """The term's model inputs per upstream draw, (D, n, q) (D = 1 without draws)."""
        base = {p.name: jnp.zeros(0) for p in self.plan.models if p.n_parameters == 0}

        def one(upstream):
            return self.plan.inputs(data["gps"], term.model, tdata["xp"], {**base, **upstream})

        if self.fixed_models:
            return jax.vmap(one)({m: data["upstream"][m] for m in self.fixed_models})
        return one({})[None]

    def term_moments(self, data, term: TermSpec, tdata, thetas):
        """Mean (n,), extra covariance (n, n), emulator var (n,) and inputs (n, q) of a
        term, on the modelled scale, averaged over the upstream draws."""
        def one(upstream):
            th = {**thetas, **upstream}
            x, mean, _ = self.plan.output(data["gps"], term.model, term.key, tdata["xp"], th)
            return x, mean

        if "x_fixed" in tdata:  # inputs precomputed (see inputs_fixed)
            x = tdata["x_fixed"]
            mean = jax.vmap(lambda xx: self.plan.predict(data["gps"], term.model, term.key,
                                                         xx, thetas[term.model])[0])(x)
        elif self.fixed_models:
            x, mean = jax.vmap(one)({m: data["upstream"][m] for m in self.fixed_models})
        else:
            x, mean = jax.tree.map(lambda a: a[None], one({}))
        d = mean.shape[0]
        m_bar, x_bar = jnp.mean(mean, axis=0), jnp.mean(x, axis=0)
        resid = mean - m_bar
        c_up = resid.T @ resid / d  # covariance of the surrogate mean over upstream draws
        var = (self.plan.predict(data["gps"], term.model, term.key, x_bar,
                                 thetas[term.model])[1]
               if term.emulator_variance else jnp.zeros_like(m_bar))
        return m_bar, c_up, var, x_bar

    def term_loglik(self, data, term: TermSpec, tdata, thetas, c):
        m_bar, c_up, var, x = self.term_moments(data, term, tdata, thetas)
        s = tdata["y_sd"]
        r = tdata["y"] - (m_bar - tdata["y_mean"]) / s
        xu = self.plan.unit_inputs(term.model, x)
        ell, sd2, se2 = c[f"ell_{term.name}"], c[f"sd2_{term.name}"], c[f"se2_{term.name}"]
        # method.md section 3: SE discrepancy + noise (+ emulator and upstream variance)
        K = sd2 * se_kernel(xu, xu, ell) + c_up / s**2
        diag = se2 + (var / s**2 if term.emulator_variance else 0.0)
        K = K + jnp.diag(diag * jnp.ones(r.shape[0]) + 1e-10)
        return mvn_logpdf_chol(r, K)

    def logdensity(self, data, u):
        c, lp = self._unpack(u)
        thetas = self.thetas(data, c)
        total = lp
        for term, tdata in zip(self.terms, data["terms"], strict=True):
            total = total + self.term_loglik(data, term, tdata, thetas, c)
        return jnp.where(jnp.isfinite(total), total, -jnp.inf)

    def constrain(self, data, u):
        return self._unpack(u)[0]

    def init(self, seed, n_chains: int):
        """Prior draws on the unconstrained scale, (n_chains, dim); seed: int or Generator."""
        return init_from_priors(self._blocks(), seed, n_chains)


@dataclass(frozen=True)
class NetworkLogDensity:
    """A :class:`NetworkKOHSpec` bound to its data (the sampler's protocol)."""

    spec: NetworkKOHSpec
    data: dict = field(repr=False)
    name: str
    parameter_names: dict[str, tuple[str, ...]]
    input_names: dict[str, tuple[str, ...]]

    @property
    def dim(self) -> int:
        return self.spec.dim

    @property
    def sampled_vars(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.spec._blocks())

    @property
    def dims(self) -> dict[str, list[str]]:
        out = {f"theta_{m}": [f"{m}_parameter"] for m, _ in self.spec.free}
        out.update({f"ell_{t.name}": [f"{t.name}_input"] for t in self.spec.terms})
        return out

    @property
    def coords(self) -> dict[str, list[str]]:
        out = {f"{m}_parameter": list(self.parameter_names[m]) for m, _ in self.spec.free}
        out.update({f"{t.name}_input": list(self.input_names[t.model])
                    for t in self.spec.terms})
        return out

    def logdensity(self, u):
        return self.spec.logdensity(self.data, u)

    def constrain(self, u):
        return self.spec.constrain(self.data, u)

    def init(self, seed: int, n_chains: int):
        return self.spec.init(seed, n_chains)


def se_kernel(xa, xb, ell):
    """Squared-exponential correlation ``exp(-0.5 sum_d (xa_d - xb_d)^2 / ell_d^2)``, (na, nb)."""
    d2 = (xa[:, None, :] - xb[None, :, :]) ** 2
    return jnp.exp(-0.5 * jnp.sum(d2 / ell**2, axis=-1))


def standardise(y: np.ndarray) -> tuple[float, float]:
    """Mean and sd used to standardise observations (sd 1 for a single point)."""
    sd = float(np.std(y)) if len(y) > 1 else 1.0
    return float(np.mean(y)), (sd if sd > 0 and math.isfinite(sd) else 1.0)
