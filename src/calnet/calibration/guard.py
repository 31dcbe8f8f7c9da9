"""Does the surrogate, rather than the data, set the answer? (a check after calibration)

At posterior draws and the calibration data's settings, each data set's surrogate
variance (the observed output's GP variance plus, to first order, the variance each
linked upstream surrogate passes down the chain) is compared with the data's own scale,
the noise variance plus the discrepancy variance at the data (after the orthogonal
discrepancy's projection, which removes what the parameters can explain). Where the
surrogate's share is large the posterior reflects the emulator's error, not the
experiments (even with clean sampler diagnostics), and more simulator runs are the
remedy: their number is estimated from how fast the surrogate's GP variance falls with
its runs, measured by conditioning it on half of them (:func:`variance_rate`).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from scipy.linalg import solve_triangular

from calnet._jax import FEW_CALLS
from calnet.calibration.koh import KOHModel
from calnet.calibration.terms import draw_index, draws_at, hyper_at, make_term, parameter_keys
from calnet.chain import ChainPlan
from calnet.spec.data import outside_bounds
from calnet.surrogates.fit import overstated_variance

#: the surrogate sd above this fraction of the data's sd triggers the warning
RATIO_WARN = 0.5
#: the estimate of runs needed aims at this fraction
RATIO_TARGET = 0.25
#: above this share of the surrogate variance at data points outside the input bounds,
#: the check names those points instead of asking for runs
OUTSIDE_SHARE = 0.5


def sd_ratio(surrogate_sd: dict[str, float], data_sd: float) -> float:
    """The surrogates' summed sd (root of the summed variances) over the data's sd."""
    total = math.sqrt(sum(v**2 for v in surrogate_sd.values()))
    return total / data_sd if data_sd > 0 else math.inf


@dataclass(frozen=True)
class SurrogateCheck:
    """The surrogate-versus-data comparison of one data set.

    Attributes
    ----------
    dataset : str
    surrogate_sd : dict of ``model.output`` -> float
        Root mean surrogate variance at the posterior draws and data settings, per
        surrogate (modelled scale, the data's units).
    data_sd : float
        Root of the mean noise plus discrepancy variance.
    runs : dict of ``model.output`` -> int
        Campaign runs behind each surrogate.
    needed : dict of ``model.output`` -> int
        Rough number of runs that would bring that surrogate's sd to RATIO_TARGET of
        the data's sd (:func:`runs_for` at ``rates``), where the check warns.
    outside : int
        Data points outside the network's input bounds, where the surrogates extrapolate.
    outside_share : float
        Their share of the summed surrogate variance.
    scale : str
        What the sds are in: ``"ln"`` for data modelled on the log scale (the sds of
        ``ln y``), else the observed output's unit (empty for none).
    rates : dict of ``model.output`` -> float or None
        :func:`variance_rate` of each surrogate: its variance falls as ``n^-rate`` (None:
        too few runs to measure).
    discrepancy : bool
        Whether the data set has a discrepancy (``data_sd`` is then not the noise's alone).
    overstated : dict of ``model.output`` -> float
        The surrogates whose variance is overstated
        (:func:`calnet.surrogates.fit.overstated_variance`), with their median |z|: more
        runs are not what they need. Looked for only where the check warns.
    """

    dataset: str
    surrogate_sd: dict[str, float]
    data_sd: float
    runs: dict[str, int]
    needed: dict[str, int]
    outside: int = 0
    outside_share: float = 0.0
    scale: str = ""
    rates: dict[str, float] = field(default_factory=dict)
    discrepancy: bool = True
    overstated: dict[str, float] = field(default_factory=dict)

    @property
    def ratio(self) -> float:
        return sd_ratio(self.surrogate_sd, self.data_sd)

    @property
    def wanting(self) -> list[str]:
        """The surrogates that need more runs than they have, largest sd first."""
        return [k for k in sorted(self.needed, key=lambda k: -self.surrogate_sd[k])
                if self.needed[k] is not None and self.needed[k] > self.runs[k]]

    @property
    def extrapolating(self) -> bool:
        """Whether data points outside the input bounds carry most of the surrogate sd."""
        return self.outside_share > OUTSIDE_SHARE

    @property
    def dominant(self) -> str:
        return max(self.surrogate_sd, key=self.surrogate_sd.get)

    def message(self) -> str | None:
        """A warning when the surrogate sets the answer, else None."""
        if self.ratio <= RATIO_WARN:
            return None
        k = self.dominant
        model = k.split(".")[0]
        total = math.sqrt(sum(v**2 for v in self.surrogate_sd.values()))
        unit = (" on the ln scale" if self.scale == "ln"
                else f" {self.scale}" if self.scale not in ("", "1") else "")
        head = (f"{self.dataset}: the surrogate, not the data, sets the answer: the surrogate "
                f"sd at the posterior ({total:.3g}{unit}) is {self.ratio:.2g} x the data's "
                + (f"noise and discrepancy sd at the data ({self.data_sd:.3g}{unit}, the "
                   "discrepancy's as it enters the likelihood there)" if self.discrepancy
                   else f"noise sd ({self.data_sd:.3g}{unit})") + f", mostly from {k}")
        if self.extrapolating:
            return (f"{head}, at the {self.outside} data point(s) outside the input bounds "
                    f"({self.outside_share:.0%} of it), where the surrogate extrapolates: "
                    "more runs inside the bounds will not help; widen the bounds and extend "
                    "the campaign over those points, or leave them out")
        if k in self.overstated:
            return (f"{head}; but {k}'s variance is overstated (at most runs its "
                    f"leave-one-out error is far below its sd: median |z| "
                    f"{self.overstated[k]:.2g} where 0.67 is expected), so more runs are not "
                    "what it needs: check with 'calnet verify', and if the surrogate agrees "
                    "with the simulator, settings.calibration.emulator_variance: false "
                    "leaves its variance out")
        rough = self.rates.get(k) is not None and self.rates[k] < RATE_MIN
        more = self.wanting
        runs = " and ".join(
            f"about {self.needed[j]} runs of '{j.split('.')[0]}' (now {self.runs[j]}; "
            + (f"{j}'s variance falls as n^-{self.rates[j]:.2g} with its runs"
               if self.rates.get(j) is not None else
               f"too few runs to measure how fast {j}'s variance falls: Matern 3/2's "
               "worst case assumed") + ")" for j in more)
        if rough:
            tail = (f"; more runs of '{model}' (now {self.runs[k]}) would barely lower it: "
                    f"{k}'s variance hardly falls when half of its runs are left out (length "
                    "scales short against the runs' spacing: a rough or discontinuous "
                    "output); check its cross-validation and 'calnet verify'")
            return head + tail + (f"; {runs} would lower the rest" if runs else "")
        return (f"{head}; {runs or 'more runs'} would bring it to {RATIO_TARGET:g} x; check "
                "with 'calnet verify'")

    def to_dict(self) -> dict:
        return {"surrogate_sd": self.surrogate_sd, "data_sd": self.data_sd,
                "ratio": self.ratio, "runs": self.runs, "runs_needed": self.needed,
                "outside_bounds": self.outside, "outside_share": self.outside_share,
                "extrapolating": self.extrapolating, "scale": self.scale,
                "variance_overstated": self.overstated,
                "variance_rates": self.rates, "target_ratio": RATIO_TARGET,
                "runs_gain_little": [k for k, r in self.rates.items()
                                     if r is not None and r < RATE_MIN],
                "needing_runs": self.wanting,
                "warning": self.message()}


def _per_surrogate(spec: KOHModel, data, tdata, thetas, hyper):
    """Variances (2 + links, n) at one draw: the discrepancy's at the data (after its
    orthogonalisation), the observed output's surrogate and each link's share."""
    term = spec.terms[0]
    x, dx, _ = spec.inputs(data, term, tdata["xp"], thetas)
    theta = thetas[term.model]
    gps = data["gps"]

    def mean_at(xx):
        return spec.plan.predict(gps, term.model, term.key, xx, theta)[0]

    _, var = spec.plan.predict(gps, term.model, term.key, x, theta)
    parts = [var]
    if dx is not None:
        parts += [jax.jvp(mean_at, (x,), (dx[k],))[1] ** 2 for k in range(dx.shape[0])]
    if term.discrepancy:
        _, K, _ = spec.train(data, term, tdata, thetas, hyper)
        noise = tdata["noise_var"] if term.noise_known else hyper["se2"]
        disc = jnp.diag(K) * tdata["y_sd"] ** 2 - noise - sum(parts)
    else:
        disc = jnp.zeros_like(var)
    return jnp.stack([disc, *parts])


@partial(jax.jit, static_argnums=0, compiler_options=FEW_CALLS)
def _over_draws(spec: KOHModel, gps, tdata, thetas, hyper):
    """:func:`_per_surrogate` at every draw, (draws, 2 + links, n); compiled once per
    network structure and shapes."""
    return jax.vmap(lambda th, h: _per_surrogate(spec, {"gps": gps}, tdata, th, h))(
        thetas, hyper)


def check_surrogates(network, surrogates, posterior, *, n_draws: int = 50,
                     directions=None) -> list[SurrogateCheck]:
    """:class:`SurrogateCheck` of every calibrated data set; ``directions``: data set ->
    the models its orthogonal discrepancy is orthogonal to
    (:func:`~calnet.calibration.calibrate_network.direction_models`; default: each
    observed model alone)."""

    plan = ChainPlan.from_network(network)
    gps = {k: s.gp for k, s in surrogates.items.items()}
    idx = draw_index(posterior.n_draws, n_draws)
    thetas = draws_at(posterior.theta, plan, idx)
    out, rates = [], {}
    for ds, hyper in posterior.hyper.items():
        d = posterior.data[ds]
        term, tdata = make_term(network, d, emulator_variance=True, plan=plan,
                                directions=(directions or {}).get(ds, ()))
        hy = hyper_at(hyper, idx, len(term.ell_priors))
        spec = KOHModel(plan, (), (), (), (term.without_priors(),))
        per_point = np.asarray(_over_draws(spec, gps, tdata, thetas, hy)).mean(axis=0)
        var = per_point.mean(axis=1)
        disc, var = max(float(var[0]), 0.0), var[1:]
        outside = outside_bounds(network, d.input_keys, d.x).any(axis=1)
        surrogate = np.clip(per_point[1:], 0.0, None).sum(axis=0)  # (n,)
        share = (float(surrogate[outside].sum() / surrogate.sum())
                 if outside.any() and surrogate.sum() > 0 else 0.0)
        keys = (term.key, *term.links)
        noise = (float(np.mean(tdata["noise_var"])) if term.noise_known
                 else float(np.mean(hyper["se2"])))
        data_sd = math.sqrt(noise + disc)
        sds = {k: math.sqrt(max(float(v), 0.0)) for k, v in zip(keys, var, strict=True)}
        runs = {k: int(surrogates[k].n_runs) for k in keys}
        warns = sd_ratio(sds, data_sd) > RATIO_WARN  # SurrogateCheck.message's test
        over = {k: m for k in keys if warns  # only a warning uses it
                and (m := overstated_variance(surrogates[k].gp)) is not None}
        needed = {}
        for k in keys if warns else ():  # without a warning no runs are counted
            if k in over:  # an overstated variance says nothing of the runs needed
                needed[k] = None
                continue
            ratio = sds[k] / data_sd if data_sd > 0 else math.inf
            factor = (ratio / RATIO_TARGET) ** 2
            if k not in rates:
                rates[k] = _cached_rate(surrogates[k].gp)
            # unmeasured (too few runs): Matern 3/2's rate in d inputs, n^(-3/d)
            rate = rates[k] if rates[k] is not None else 3.0 / surrogates[k].gp.n_inputs
            needed[k] = runs_for(runs[k], factor, rate)
        observed = network.observed(network.dataset(ds))
        scale = "ln" if observed.transform == "log" else (observed.unit or "")
        out.append(SurrogateCheck(ds, sds, data_sd, runs, needed, int(outside.sum()), share,
                                  scale, {k: rates[k] for k in keys if k in rates},
                                  bool(term.discrepancy), over))
    return out


#: the slowest rate of a surrogate's variance with its runs (var ~ n^-rate) that the
#: runs-needed estimate uses; a GP whose variance falls slower than this is said to gain
#: little from more runs
RATE_MIN = 0.05
#: most runs a surrogate check's estimate names
RUNS_MAX = 1_000_000


def runs_for(n: int, factor: float, rate: float) -> int | None:
    """Runs that divide a surrogate's variance by ``factor`` from ``n`` runs when it falls
    as ``n^-rate`` (at most :data:`RUNS_MAX`); None where it barely falls (``rate`` below
    :data:`RATE_MIN`)."""
    if factor <= 1.0:
        return int(n)
    if rate < RATE_MIN:
        return None
    return int(math.ceil(min(RUNS_MAX, n * factor ** (1.0 / rate))))


_RATES: OrderedDict = OrderedDict()  # id(gp) -> (gp, rate): the refits check the same GPs


def _cached_rate(gp) -> float | None:
    hit = _RATES.get(id(gp))
    if hit is not None and hit[0] is gp:
        _RATES.move_to_end(id(gp))
        return hit[1]
    rate = variance_rate(gp)
    _RATES[id(gp)] = (gp, rate)
    while len(_RATES) > 16:
        _RATES.popitem(last=False)
    return rate


def variance_rate(gp, *, seed: int = 0, most: int = 800, repeats: int = 4) -> float | None:
    """How fast ``gp``'s variance falls with its runs: ``r`` in ``var ~ n^-r``.

    A quarter of the training runs is held out; the GP, its hyperparameters fixed, is
    conditioned on the other runs and on random halves of them, and ``r`` compares its
    mean latent variance (the nugget left out) at the held-out runs: ``log(v_half /
    v_all) / log 2``. The held-out runs sit where the campaign put runs, so the rate is
    that of the design's own region. Matern 3/2 with space-filling runs falls as
    ``n^(-3/d)`` in ``d`` inputs at worst; a smooth response or inactive inputs (long
    length scales) fall faster. At most ``most`` runs are used (a random subset). The
    variance is the kernel's; a linear mean's share (its coefficients' uncertainty, which
    falls as ``1/n``) is left out.
    Returns 0 where the variance does not fall (length scales short against the runs'
    spacing), None where it cannot be measured (fewer than 8 runs, a singular matrix).
    """
    x = np.asarray(gp.x_train, float)
    n = len(x)
    if n < 8:
        return None
    rng = np.random.default_rng(seed)
    if n > most:
        x = x[rng.choice(n, most, replace=False)]
        n = most
    ell = np.asarray(gp.lengthscales, float)
    s2, nug = float(gp.signal_var), float(gp.nugget)
    order = rng.permutation(n)
    held, rest = x[order[: n // 4]], x[order[n // 4:]]

    def corr(a, b):
        r2 = np.zeros((len(a), len(b)))
        for j in range(a.shape[1]):  # one input at a time: (m, n) arrays, not (m, n, d)
            r2 += ((a[:, j, None] - b[None, :, j]) / ell[j]) ** 2
        r = np.sqrt(3.0 * r2)
        return (1.0 + r) * np.exp(-r)

    def mean_var(train):
        k = s2 * corr(train, train) + nug * np.eye(len(train))
        chol = np.linalg.cholesky(k)
        v = solve_triangular(chol, s2 * corr(train, held), lower=True)
        return float(np.mean(np.maximum(s2 - np.sum(v**2, axis=0), 0.0)))

    try:
        full = mean_var(rest)
        half = np.mean([mean_var(rest[rng.choice(len(rest), len(rest) // 2, replace=False)])
                        for _ in range(repeats)])
    except np.linalg.LinAlgError:
        return None
    if not full > 0:  # known to round-off at the held-out runs: nothing to measure
        return None
    if not half > full:
        return 0.0
    return float(np.log(half / full) / np.log(len(rest) / (len(rest) // 2)))


#: a posterior median within this fraction of the range from a bound ...
BOUND_NEAR = 0.03
#: ... with a 95 % interval narrower than this fraction of the range is pressed against it
BOUND_NARROW = 0.6


def check_bounds(network, posterior) -> list[str]:
    """A message for every calibrated parameter whose posterior presses against one of
    its bounds: the data ask for values the bounds (and the campaign) exclude."""
    out, seen = [], set()
    for model, draws in posterior.theta.items():
        if model in posterior.prior_only:
            continue
        orthogonal = any(d.discrepancy.enabled and d.discrepancy.orthogonal
                         for d in network.datasets_for(model))
        for j, (p, key) in enumerate(zip(network.model(model).parameters,
                                         parameter_keys(network, model), strict=True)):
            if key in seen:
                continue
            seen.add(key)
            lo, med, hi = np.percentile(draws[:, j], [2.5, 50, 97.5])
            width = p.upper - p.lower
            if hi - lo > BOUND_NARROW * width:
                continue
            below, _, above = p.prior_shares()
            for side, bound, beyond in (("lower", p.lower, below), ("upper", p.upper, above)):
                if abs(med - bound) < BOUND_NEAR * width:
                    hint = (" (with discrepancy: {orthogonal: false} the discrepancy may take "
                            "up that misfit instead)" if orthogonal else "")
                    out.append(f"{model}.{p.name}: the posterior presses against its {side} "
                               f"bound {bound:g} (median {med:.4g}); "
                               + (_prior_beyond(p, side, bound, beyond) if beyond > 0.5
                                  else _data_beyond(p)) + hint)
    return out


def _data_beyond(p) -> str:
    return (f"the data ask for values outside [{p.lower:g}, {p.upper:g}]: widen the bounds "
            "and extend the campaign if such values are physical, otherwise the model misses "
            "what this parameter stands in for")


def _prior_beyond(p, side: str, bound: float, beyond: float) -> str:
    """The remedy when the prior's own median lies beyond the bound pressed against."""
    where = "below" if side == "lower" else "above"
    return (f"the prior or the data ask for values outside [{p.lower:g}, {p.upper:g}]: the "
            f"prior {p.prior_text()} puts {100 * beyond:.3g} % of its mass {where} {bound:g}; "
            "move the prior into the bounds if it is not meant to sit there, otherwise widen "
            "the bounds and extend the campaign")
