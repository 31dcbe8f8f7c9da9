"""Convergence diagnostics and posterior summaries of a calibration run.

:func:`summarize` turns the ``InferenceData`` of :func:`~calnet.calibration.sampling.sample_nuts`
into a frozen :class:`PosteriorSummary` (R-hat, bulk/tail ESS, divergences, means, sd,
KDE posterior modes, HDIs; ArviZ underneath) whose ``to_dict()`` goes to metrics.json,
and warns with :class:`~calnet.errors.CalibrationWarning` when R-hat > 1.01, bulk
ESS < 400 or there are divergent transitions (method.md section 3: report them; the
reference study reports posterior modes as point estimates).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.stats import gaussian_kde

from calnet.errors import CalibrationWarning
from calnet.results import rhat_text

__all__ = ["ParameterSummary", "PosteriorSummary", "summarize", "kde_mode", "import_arviz",
           "RHAT_MAX", "ESS_MIN"]

RHAT_MAX = 1.01  # Vehtari et al. (2021)
ESS_MIN = 400  # bulk ESS, 100 per chain for 4 chains (Vehtari et al. 2021)


# ArviZ >= 0.22 warns once a day, at import, that it "is undergoing a major refactor":
# a FutureWarning about ArviZ itself, nothing about the user's run
_ARVIZ_BANNER = r"\s*ArviZ is undergoing a major refactor"


#: the advice of a low bulk ESS
MORE_DRAWS = "raise settings.sampler.draws"


def import_arviz():
    """``arviz``, imported without its once-a-day refactor notice (and only that)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=_ARVIZ_BANNER, category=FutureWarning)
        import arviz

    return arviz


def kde_mode(draws, grid_size: int = 512) -> float:
    """Posterior mode of 1-D draws: argmax of a Gaussian KDE on a grid over their range."""
    x = np.asarray(draws, dtype=float).ravel()
    lo, hi = float(x.min()), float(x.max())
    if not hi > lo:  # constant draws
        return lo
    grid = np.linspace(lo, hi, grid_size)
    return float(grid[np.argmax(gaussian_kde(x)(grid))])


@dataclass(frozen=True)
class ParameterSummary:
    """Summary of one scalar posterior quantity (e.g. ``theta[K_S]``)."""

    name: str
    mean: float
    sd: float
    mode: float
    hdi: dict[float, tuple[float, float]]
    r_hat: float
    ess_bulk: float
    ess_tail: float
    mcse_mean: float
    chains_apart: float = 0.0  # spread of the chains' means over the largest within-chain sd

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("mean", "sd", "mode", "r_hat", "ess_bulk",
                                           "ess_tail", "mcse_mean")}
        for prob, (lo, hi) in self.hdi.items():
            d[f"hdi_{round(100 * prob)}"] = [lo, hi]
        return d


@dataclass(frozen=True)
class PosteriorSummary:
    """Diagnostics and summaries of one calibration run; see :func:`summarize`."""

    model: str
    parameters: tuple[ParameterSummary, ...]
    n_chains: int
    n_draws: int
    divergences: int
    sampling_time: float
    compile_time: float

    @property
    def max_r_hat(self) -> float:
        return max(p.r_hat for p in self.parameters)

    @property
    def min_ess_bulk(self) -> float:
        return min(p.ess_bulk for p in self.parameters)

    @property
    def min_ess_tail(self) -> float:
        return min(p.ess_tail for p in self.parameters)

    @property
    def converged(self) -> bool:
        return (self.max_r_hat <= RHAT_MAX and self.min_ess_bulk >= ESS_MIN
                and self.divergences == 0)

    def __getitem__(self, name: str) -> ParameterSummary:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(f"{name!r}; known: {[p.name for p in self.parameters]}")

    def modes(self) -> dict[str, float]:
        """``{name: posterior mode}``."""
        return {p.name: p.mode for p in self.parameters}

    def to_dict(self) -> dict:
        """JSON-ready dict for metrics.json."""
        return {"model": self.model, "n_chains": self.n_chains, "n_draws": self.n_draws,
                "divergences": self.divergences, "max_r_hat": self.max_r_hat,
                "min_ess_bulk": self.min_ess_bulk, "min_ess_tail": self.min_ess_tail,
                "converged": self.converged, "sampling_time_s": self.sampling_time,
                "compile_time_s": self.compile_time,
                "parameters": {p.name: p.to_dict() for p in self.parameters}}


def _scalar_names(da) -> list[tuple[str, dict]]:
    """``(label, selection)`` for every scalar component of a posterior variable."""
    extra = [d for d in da.dims if d not in ("chain", "draw")]
    if not extra:
        return [(da.name, {})]
    (dim,) = extra  # calibration variables are at most 1-D per draw
    return [(f"{da.name}[{c}]", {dim: c}) for c in da.coords[dim].values.tolist()]


def summarize(idata, *, hdi_probs: tuple[float, ...] = (0.94, 0.95), warn: bool = True,
              stacklevel: int = 2) -> PosteriorSummary:
    """Summarise a calibration posterior; warn if it has not converged.

    Parameters
    ----------
    idata : arviz.InferenceData
        From :func:`~calnet.calibration.sampling.sample_nuts`.
    hdi_probs : tuple of float
        Probabilities of the highest-density intervals reported.
    warn : bool
        Emit :class:`~calnet.errors.CalibrationWarning` for R-hat > 1.01, bulk ESS < 400
        or divergences > 0.
    stacklevel : int
        Passed to :func:`warnings.warn` (2: the caller of ``summarize``).

    Returns
    -------
    PosteriorSummary
    """
    az = import_arviz()
    post = idata.posterior
    rhat, ess_b = az.rhat(_halves(post)), az.ess(post, method="bulk")
    ess_t, mcse = az.ess(post, method="tail"), az.mcse(post, method="mean")
    hdis = {prob: az.hdi(post, hdi_prob=prob) for prob in hdi_probs}
    params = []
    for var in post.data_vars:
        for label, sel in _scalar_names(post[var]):
            draws = post[var].sel(sel).values
            params.append(ParameterSummary(
                name=label, mean=float(draws.mean()), sd=float(draws.std(ddof=1)),
                mode=kde_mode(draws),
                hdi={p: tuple(float(v) for v in hdis[p][var].sel(sel).values)
                     for p in hdi_probs},
                r_hat=float(rhat[var].sel(sel)), ess_bulk=float(ess_b[var].sel(sel)),
                ess_tail=float(ess_t[var].sel(sel)), mcse_mean=float(mcse[var].sel(sel)),
                chains_apart=_apart(draws)))
    ss = idata.sample_stats
    summary = PosteriorSummary(
        model=str(post.attrs.get("model", "model")), parameters=tuple(params),
        n_chains=post.sizes["chain"], n_draws=post.sizes["draw"],
        divergences=int(np.asarray(ss["diverging"]).sum()) if "diverging" in ss else 0,
        sampling_time=float(post.attrs.get("sampling_time", np.nan)),
        compile_time=float(post.attrs.get("compile_time", np.nan)))
    if warn:
        for message in convergence_problems(summary):
            warnings.warn(message, CalibrationWarning, stacklevel=stacklevel)
    return summary


SEPARATE_MODES = 10.0  # chains whose means lie this many within-chain sds apart


def _apart(draws: np.ndarray) -> float:
    """Spread of the chains' means of ``draws`` (chain, draw) in units of the largest
    within-chain sd (0 for one chain)."""
    draws = np.asarray(draws, dtype=float)
    if draws.ndim != 2 or draws.shape[0] < 2:
        return 0.0
    means, sds = draws.mean(axis=1), draws.std(axis=1)
    return float(np.ptp(means) / max(float(sds.max()), 1e-300))


def _halves(post):
    """``post`` itself, or for a single chain its two halves as two chains: R-hat then
    compares them, as split R-hat does within chains, instead of ArviZ logging that one
    chain is too few and returning NaN."""
    if post.sizes["chain"] > 1:
        return post
    import xarray as xr

    half = post.sizes["draw"] // 2
    first = post.isel(chain=[0], draw=slice(0, half))
    second = post.isel(chain=[0], draw=slice(half, 2 * half)).assign_coords(
        chain=[1], draw=first.draw.values)
    return xr.concat([first, second], dim="chain")


_LABEL = re.compile(r"^(theta_shared|theta|ell|sd2|se2)(?:_(.+?))?(?:\[(.+)\])?$")


def readable(name: str) -> str:
    """A posterior variable's label in a user's words: ``theta_M2[b]`` -> ``M2.b``,
    ``theta_shared[c]`` -> ``c (shared)``, ``ell_d1[x]`` -> ``the discrepancy length
    scale of d1 along x``, ``sd2_d1`` / ``se2_d1`` -> the discrepancy / noise variance
    of d1; anything else as it is."""
    m = _LABEL.match(name)
    if not m:
        return name
    kind, owner, coord = m.groups()
    if kind == "theta_shared" and coord:
        return f"{coord} (shared)"
    if kind == "theta" and owner and coord:
        return f"{owner}.{coord}"
    if kind == "ell" and owner:
        return f"the discrepancy length scale of {owner}" + (f" along {coord}" if coord else "")
    if kind == "sd2" and owner and not coord:
        return f"the discrepancy variance of {owner}"
    if kind == "se2" and owner and not coord:
        return f"the noise variance of {owner}"
    return name


STUCK_GAP = 10.0
"""Log-density units: a chain whose mean log density lies further than this (and
:data:`STUCK_SDS` of its fluctuations) below the best chain's sits in a local mode."""
STUCK_SDS = 10.0


def stuck_chains(lp) -> list[int]:
    """Chains stuck in a local mode far below the best chain's: their mean log density
    lies below the best chain's by more than :data:`STUCK_GAP` and by more than
    :data:`STUCK_SDS` times the best chain's standard deviation of the log density (the
    stuck chain's own is no yardstick: one that leaves the trap part-way has a wide one).
    ``lp`` is (chains, draws).

    Chains of one mode differ in mean log density by about its standard deviation over
    the square root of the effective sample size; a gap of 10 log units is a density
    ratio of 2e4, so such a mode carries a negligible share of the posterior unless its
    volume were larger by nearly as much (a mode 10 times wider in each of 4 parameters),
    while a chain kept in it would carry a whole chain's share of the draws. NUTS cannot
    leave it: a chain started in its basin stays there.
    """
    lp = np.asarray(lp, dtype=float)
    if lp.ndim != 2 or lp.shape[0] < 2:
        return []
    mean, sd = lp.mean(axis=1), lp.std(axis=1)
    best = int(np.argmax(mean))
    bar = max(STUCK_GAP, STUCK_SDS * sd[best])
    return [int(c) for c in np.flatnonzero(mean[best] - mean > bar)]


UNVISITED_SDS = 10.0  # posterior sds from every chain for a plausible point to be unvisited
UNVISITED_LP = 0.01  # quantile of the draws' log densities a candidate must reach


def unvisited_mode(positions, lp, candidates, candidate_lp) -> int | None:
    """Index of a candidate point (one of the prior draws the chains were started from)
    that is as plausible as the draws but far from every chain: its log density is at
    least the :data:`UNVISITED_LP` quantile of the draws' (not their lowest: a chain's
    rare excursion into a tail would let any tail point pass), and in some parameter it
    lies more than
    :data:`UNVISITED_SDS` of each chain's own sd from that chain's mean. Such a point sits
    in a mode the chains did not visit (a mode's share is then set by how many chains
    landed in it, not by its mass). None when there is none; the candidate with the
    highest log density when there are several.

    ``positions`` (chains, draws, dim), ``lp`` (chains, draws), ``candidates`` (n, dim),
    ``candidate_lp`` (n,), all on the sampled (unconstrained) scale.
    """
    positions, lp = np.asarray(positions, float), np.asarray(lp, float)
    candidates, candidate_lp = np.asarray(candidates, float), np.asarray(candidate_lp, float)
    plausible = np.isfinite(candidate_lp) & (candidate_lp >= np.quantile(lp, UNVISITED_LP))
    if not plausible.any():
        return None
    mean = positions.mean(axis=1)  # (chains, dim)
    sd = positions.std(axis=1) + 1e-12 * (1.0 + np.abs(mean))
    z = np.abs(candidates[:, None, :] - mean[None]) / sd[None]  # (n, chains, dim)
    far = plausible & np.all(z.max(axis=2) > UNVISITED_SDS, axis=1)
    if not far.any():
        return None
    return int(np.flatnonzero(far)[np.argmax(candidate_lp[far])])


def convergence_problems(summary: PosteriorSummary) -> list[str]:
    """One message per failed check (R-hat, bulk ESS, divergences); empty when fine."""
    out, m = [], summary.model
    if summary.max_r_hat > RHAT_MAX:
        worst = max(summary.parameters, key=lambda p: p.r_hat)
        what = ("the two halves of the only chain disagree - raise settings.sampler.warmup "
                "and draws, and run several chains (settings.sampler.chains), which also "
                "show modes that one chain never leaves" if summary.n_chains == 1 else
                f"the chains sit in separate modes (their means lie {worst.chains_apart:.0f} "
                "within-chain sds apart): more draws will not join them, and each mode's "
                "share of the draws is the share of the chains that landed in it, not its "
                "mass; compare runs with other seeds, and add data or bounds that tell the "
                "modes apart" if worst.chains_apart > SEPARATE_MODES else
                "chains disagree - raise settings.sampler.warmup and draws; chains that "
                "still disagree sit in separate modes the data cannot tell apart")
        out.append(f"{m}: R-hat {rhat_text(worst.r_hat)} > {RHAT_MAX} for "
                   f"{readable(worst.name)}; {what}")
    if summary.min_ess_bulk < ESS_MIN:
        worst = min(summary.parameters, key=lambda p: p.ess_bulk)
        out.append(f"{m}: bulk ESS {worst.ess_bulk:.0f} < {ESS_MIN} for "
                   f"{readable(worst.name)}; {MORE_DRAWS}")
    if summary.divergences > 0:
        out.append(f"{m}: {summary.divergences} divergent transitions; raise "
                   "settings.sampler.target_accept (e.g. 0.95)")
    return out
