"""The network as a pure JAX function of process inputs, parameters and surrogates.

Given the free (process) inputs of the network and a parameter vector per model, every
model's control inputs follow by walking the links in topological order: a free input is
read from the process inputs, an identity link passes a control input through, and an
output link evaluates the upstream surrogate (natural scale: ``exp`` of the modelled mean
for a log-modelled output, i.e. its median). method.md sections 4-5.

:class:`ChainPlan` is the static, hashable part (it can key a compiled sampler); the
surrogates travel as a pytree ``gps`` (``"model.output" -> FittedGP``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from calnet.spec import Network

Array = jax.Array


@dataclass(frozen=True)
class ModelPlan:
    """How one model's inputs are obtained and which of its GP inputs are logged.

    ``sources[j]`` is ``("free", "model.input")``, ``("identity", model, index)`` or
    ``("output", model, "model.output")``.
    """

    name: str
    sources: tuple[tuple, ...]
    n_parameters: int
    log_mask: tuple[bool, ...]  # over inputs + parameters
    lower: tuple[float, ...]  # input bounds in the GP space (for discrepancy scaling)
    upper: tuple[float, ...]


@dataclass(frozen=True)
class ChainPlan:
    """Static description of the network's data flow; build with :meth:`from_network`."""

    models: tuple[ModelPlan, ...]

    @classmethod
    def from_network(cls, network: Network) -> ChainPlan:
        plans = []
        for name in network.order:
            model = network.model(name)
            sources = []
            for var in model.inputs:
                link = network.link_into(name, var.name)
                if link is None:
                    sources.append(("free", f"{name}.{var.name}"))
                    continue
                src = network.model(link.source_model)
                if link.source_var in src.input_names:
                    sources.append(("identity", src.name, src.input_names.index(link.source_var)))
                else:
                    sources.append(("output", src.name, link.source))
            mask = tuple(getattr(v, "scale", "linear") == "log"
                         for v in (*model.inputs, *model.parameters))
            lo = tuple(jnp.log(v.lower).item() if m else v.lower
                       for v, m in zip(model.inputs, mask, strict=False))
            hi = tuple(jnp.log(v.upper).item() if m else v.upper
                       for v, m in zip(model.inputs, mask, strict=False))
            plans.append(ModelPlan(name, tuple(sources), len(model.parameters), mask, lo, hi))
        return cls(tuple(plans))

    def model(self, name: str) -> ModelPlan:
        for plan in self.models:
            if plan.name == name:
                return plan
        raise KeyError(name)

    # ------------------------------------------------------------ evaluation
    def inputs(self, gps: Mapping, model: str, xp: Mapping[str, Array],
               thetas: Mapping[str, Array], eps: Mapping[str, Array] | None = None) -> Array:
        """Control inputs of ``model``, shape (n, n_inputs), physical units."""
        return self._inputs(gps, model, xp, thetas, eps or {}, {})

    def _inputs(self, gps, model, xp, thetas, eps, cache) -> Array:
        if model in cache:
            return cache[model]
        cols = []
        for src in self.model(model).sources:
            if src[0] == "free":
                cols.append(jnp.asarray(xp[src[1]], dtype=float))
            elif src[0] == "identity":
                cols.append(self._inputs(gps, src[1], xp, thetas, eps, cache)[:, src[2]])
            else:
                up = self._inputs(gps, src[1], xp, thetas, eps, cache)
                if src[2] in eps:  # + 1e-30: a finite derivative where the variance is 0
                    mean, var = self.predict(gps, src[1], src[2], up, thetas[src[1]])
                    mean = mean + jnp.sqrt(var + 1e-30) * eps[src[2]]
                else:  # the mean alone: no solve with the training covariance
                    mean = self.predict_mean(gps, src[1], src[2], up, thetas[src[1]])
                cols.append(jnp.exp(mean) if gps[src[2]].transform == "log" else mean)
        out = jnp.stack(cols, axis=1)
        cache[model] = out
        return out

    def gp_inputs(self, model: str, x: Array, theta: Array) -> Array:
        """Physical ``[x, theta]`` (n, d) in the GP's input space (logs where declared)."""
        plan = self.model(model)
        theta = jnp.broadcast_to(jnp.asarray(theta, dtype=float), (x.shape[0], plan.n_parameters))
        z = jnp.concatenate([x, theta], axis=1)
        mask = jnp.asarray(plan.log_mask)
        if not any(plan.log_mask):
            return z
        return jnp.where(mask, jnp.log(jnp.where(mask, z, 1.0)), z)

    def predict(self, gps: Mapping, model: str, key: str, x: Array, theta: Array):
        """GP ``key`` of ``model`` at inputs ``x`` (n, n_inputs): modelled mean, var (n,)."""
        return gps[key].predict(self.gp_inputs(model, x, theta))

    def predict_mean(self, gps: Mapping, model: str, key: str, x: Array, theta: Array):
        """GP ``key`` of ``model`` at inputs ``x`` (n, n_inputs): modelled mean (n,)."""
        return gps[key].predict_mean(self.gp_inputs(model, x, theta))

    def predict_cov(self, gps: Mapping, model: str, key: str, x: Array, theta: Array):
        """GP ``key`` at inputs ``x`` (n, n_inputs): modelled mean (n,) and covariance (n, n)."""
        return gps[key].predict_cov(self.gp_inputs(model, x, theta))

    def at_controls(self, gps: Mapping, model: str, key: str, x: Array) -> dict:
        """:meth:`FittedGP.at_controls` of GP ``key`` at control inputs ``x`` (n, q)."""
        q = x.shape[1]
        z = self.gp_inputs(model, x, jnp.ones(self.model(model).n_parameters))[:, :q]
        return gps[key].at_controls(z)

    def moments_at(self, gps: Mapping, model: str, key: str, fixed: dict, theta: Array, *,
                   cov: bool):
        """GP ``key`` at fixed control inputs (``fixed`` from :meth:`at_controls`) and
        parameters ``theta``: modelled mean (n,) and covariance (n, n) or None."""
        plan = self.model(model)
        q = len(plan.sources)
        mask = jnp.asarray(plan.log_mask[q:])
        t = jnp.asarray(theta, dtype=float)
        if any(plan.log_mask[q:]):
            t = jnp.where(mask, jnp.log(jnp.where(mask, t, 1.0)), t)
        return gps[key].moments_at(fixed, t, cov=cov)

    def output(self, gps: Mapping, model: str, key: str, xp: Mapping[str, Array],
               thetas: Mapping[str, Array], eps: Mapping[str, Array] | None = None):
        """Inputs (n, n_inputs) of ``model`` and the modelled mean and var (n,) of ``key``."""
        x = self.inputs(gps, model, xp, thetas, eps)
        mean, var = self.predict(gps, model, key, x, thetas[model])
        return x, mean, var

    def unit_inputs(self, model: str, x: Array) -> Array:
        """Control inputs scaled to the unit cube of the model's bounds (logs where
        declared): the discrepancy's input space."""
        plan = self.model(model)
        n_in = len(plan.sources)
        mask = jnp.asarray(plan.log_mask[:n_in])
        z = jnp.where(mask, jnp.log(jnp.where(mask, x, 1.0)), x) if any(plan.log_mask[:n_in]) else x
        lo, hi = jnp.asarray(plan.lower), jnp.asarray(plan.upper)
        return (z - lo) / (hi - lo)
