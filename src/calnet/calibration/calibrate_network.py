"""Calibration of a network, segmented or joint (method.md section 4).

``calibrate(network, surrogates)`` builds the network's KOH model
(:mod:`calnet.calibration.koh`) and samples it. *Joint*: one posterior over every
calibration parameter and every data set's discrepancy and noise. *Segmented*: the models
are calibrated in topological order, each on its own data sets with the parameters that
earlier stages calibrated held fixed (the parameters of an upstream model without data
of its own are calibrated in the first stage after it with data, which they act on):

* ``plug="mode"``: at their posterior mode (KDE), as the reference study did;
* ``plug="posterior"``: the *cut* posterior (theta_up from its own posterior, the stage's
  variables conditional on it), by linear response: the stage is sampled once at the
  upstream posterior mean, the sensitivity ``J = d E[u | theta_up] / d theta_up`` of its
  posterior mean is the posterior covariance of ``u`` with ``d loglik / d theta_up``
  (exact for the mean), and each draw is moved by ``J (theta_up^(s) - mean)`` with an
  upstream draw ``theta_up^(s)``. Exact for a linear-Gaussian chain; to first order in
  the upstream spread otherwise. Its cost does not depend on the number of upstream draws.

A parameter declared ``shared: true`` in several models is one parameter: joint mode
calibrates it with every data set; segmented mode calibrates it in the first model (in
topological order) that has data it acts on, and plugs it into the later ones.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from calnet._jax import device_array
from calnet.calibration.diagnostics import (
    PosteriorSummary,
    convergence_problems,
    kde_mode,
    summarize,
)
from calnet.calibration.guard import check_bounds, check_surrogates
from calnet.calibration.koh import KOHDensity, KOHModel, Term
from calnet.calibration.priors import parameter_prior
from calnet.calibration.sampling import sample_nuts
from calnet.calibration.terms import (
    data_scale,
    make_term,
    modelled,
    no_spread,
    parameter_keys,
)
from calnet.chain import ChainPlan
from calnet.errors import CalibrationError, CalibrationWarning
from calnet.progress import Lines
from calnet.spec import ExperimentalData, Network, read_all
from calnet.spec.models import SamplerSettings
from calnet.surrogates.fit_network import Surrogates


@dataclass(frozen=True)
class StageResult:
    """One sampled posterior: the free models and data sets of one stage."""

    models: tuple[str, ...]
    datasets: tuple[str, ...]
    idata: object  # arviz.InferenceData
    logdensity: KOHDensity
    #: R-hat, ESS and the other diagnostics of ``idata`` where the calibration computed
    #: them (None where it did not, e.g. for a stage moved by linear response)
    diagnostics: PosteriorSummary | None = field(default=None, compare=False, repr=False)
    #: keys of the upstream parameters whose posterior draws moved this stage's draws
    #: (segmented, ``plug="posterior"``): the draws carry those stages' uncertainty and
    #: their convergence
    moved_by: tuple[str, ...] = ()

    def draws(self, var: str) -> np.ndarray:
        """Flattened draws of a posterior variable, shape (chains * draws, ...)."""
        arr = np.asarray(self.idata.posterior[var].values)
        return arr.reshape((-1,) + arr.shape[2:])


@dataclass(frozen=True)
class NetworkPosterior:
    """Posterior of a network calibration.

    Attributes
    ----------
    mode, plug : str
        How it was calibrated (``plug`` is ``"-"`` for joint).
    stages : tuple of StageResult
        One per sampled posterior (one for joint; one per model with data, segmented).
    theta : dict of model -> ndarray (n_draws, n_parameters)
        Parameter draws per model in declared order, aligned across models (row s of
        every model is one draw of the network; a shared parameter has the same value in
        every model that declares it).
    hyper : dict of data set -> dict of ndarray
        ``ell`` (n_draws, q) and ``sd2`` (n_draws,) where the data set has a discrepancy,
        ``se2`` (n_draws,) where its noise is sampled; data units on the modelled scale.
    data : dict of data set -> ExperimentalData used (training rows)
    prior_only : tuple of str
        Models left at their prior (segmented, no data of their own or downstream).
    plugged : dict of model -> ndarray (n_parameters,)
        Segmented: the values of the model's parameters held fixed in later stages (the
        KDE mode for ``plug="mode"``, the posterior mean for ``plug="posterior"``).
    notes : tuple of str
        Problems of the posterior that a calibration without warnings kept (convergence,
        surrogate checks, bounds); with warnings on they are warned instead.
    checks : tuple of SurrogateCheck
        Per data set, the surrogates' sd at the posterior against the data's
        (:mod:`calnet.calibration.guard`).
    """

    mode: str
    plug: str
    stages: tuple[StageResult, ...]
    theta: Mapping[str, np.ndarray]
    hyper: Mapping[str, Mapping[str, np.ndarray]]
    data: Mapping[str, ExperimentalData]
    prior_only: tuple[str, ...] = ()
    timings: Mapping[str, float] = field(default_factory=dict)
    plugged: Mapping[str, np.ndarray] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    checks: tuple = ()
    #: how the calibration was set up where a user may not expect it (segmented mode: which
    #: stage calibrates a shared parameter or a model without data): said, not warned
    info: tuple[str, ...] = ()

    @property
    def n_draws(self) -> int:
        """Draws of the network: of its parameters, else of its data sets' noise and
        discrepancy; 0 for a network with neither (nothing was sampled)."""
        for arrays in (self.theta, *self.hyper.values()):
            if arrays:
                return next(iter(arrays.values())).shape[0]
        return 0

    @property
    def calibrated(self) -> bool:
        """Whether anything was sampled against data (False without data sets)."""
        return bool(self.data)


def _parameter(network: Network, key: str):
    for m in network.order:
        for p in network.model(m).parameters:
            if network.param_key(m, p.name) == key:
                return m, p
    raise KeyError(key)


def _layout(network: Network, free: list[str]):
    params = tuple((k, parameter_prior(_parameter(network, k)[1])) for k in free)
    theta_index, groups, names = [], [], {}
    for m in network.order:
        keys = parameter_keys(network, m)
        theta_index.append((m, tuple(free.index(k) if k in free else -1 for k in keys)))
        private = [k for k in free if k.startswith(f"{m}.")]
        if private:
            groups.append((f"theta_{m}", tuple(free.index(k) for k in private)))
            names[f"theta_{m}"] = tuple(k.split(".", 1)[1] for k in private)
    shared = [k for k in free if "." not in k]
    if shared:
        groups.append(("theta_shared", tuple(free.index(k) for k in shared)))
        names["theta_shared"] = tuple(shared)
    return params, tuple(theta_index), tuple(groups), names


def build_koh(network: Network, surrogates: Surrogates, *, free: list[str],
              datasets: Mapping[str, ExperimentalData], fixed: Mapping[str, float] | None = None,
              emulator_variance: bool = True, name: str = "network",
              plan: ChainPlan | None = None,
              scales: Mapping[str, tuple[float, float]] | None = None,
              directions: Mapping[str, tuple[str, ...]] | None = None) -> KOHDensity:
    """The KOH log-density of ``datasets`` with the parameters ``free`` (keys) sampled and
    the others at ``fixed`` (key -> value; 0 where neither). ``directions`` (data set ->
    models) sets what a data set's orthogonal discrepancy is orthogonal to where it is
    not that of ``free`` (a leave-one-out refit that holds some of the calibration's
    parameters fixed keeps the calibration's discrepancy)."""
    plan = plan or ChainPlan.from_network(network)
    fixed = dict(fixed or {})
    params, theta_index, groups, names = _layout(network, list(free))
    terms, tdata = [], []
    for ds_name, d in datasets.items():
        scale = (scales or {}).get(ds_name)
        if scale is None:
            scale = data_scale(network, d, surrogates)
            _warn_no_spread(network, d, scale[1], name)
        observed = network.dataset(ds_name).observed_model
        sampled = (directions or {}).get(ds_name)
        if sampled is None:
            sampled = _models_sampled(network, observed, free)
        t, td = make_term(network, d, emulator_variance=emulator_variance, plan=plan,
                          scale=scale, directions=sampled)
        terms.append(t)
        tdata.append(td)
        if t.discrepancy:
            names[f"ell_{ds_name}"] = network.model(t.model).input_names
    # host arrays handed over whole: an eager JAX operation would compile a program
    theta_fixed = {m: device_array([fixed.get(k, 0.0) for k in parameter_keys(network, m)],
                                   float)
                   for m in network.order}
    spec = KOHModel(plan, params, theta_index, groups, tuple(terms))
    data = {"gps": {k: s.gp for k, s in surrogates.items.items()}, "theta_fixed": theta_fixed,
            "terms": tdata,
            "y": device_array(np.concatenate([np.asarray(t["y"]) for t in tdata])
                              if tdata else np.zeros(0), float)}
    index = dict(theta_index)
    for term, td in zip(terms, tdata, strict=True):
        if all(i < 0 for m in network.ancestors(term.model) for i in index[m]):
            # no sampled parameter upstream: the model's inputs are computed once
            td.update(_fixed_inputs(spec, term, data["gps"], td["xp"], theta_fixed))
    keys = {m: tuple(parameter_keys(network, m)) for m in network.order}
    ld = KOHDensity(spec, data, name, names, keys)
    n_obs = sum(len(d.y) for d in datasets.values())
    if n_obs < ld.dim:
        warnings.warn(f"{name}: {n_obs} data point{'' if n_obs == 1 else 's'} for "
                      f"{ld.dim} sampled parameters "
                      "(calibration parameters and discrepancy hyperparameters); the "
                      "posterior will lean on the priors", CalibrationWarning, stacklevel=2)
    return ld


def _warn_no_spread(network: Network, data: ExperimentalData, sd: float, name: str
                    ) -> None:
    """Warn where a data set's observations have no spread and a default prior needs
    their sd (:func:`~calnet.calibration.terms.data_scale`)."""
    ds = network.dataset(data.name)
    y = modelled(network, data)
    if not no_spread(y):
        return
    noise = not ds.noise.known and ds.noise.prior is None
    disc = ds.discrepancy.enabled and ds.discrepancy.sd_prior is None
    if not (noise or disc):
        return
    out = network.observed(ds)
    what = " and ".join(w for w, used in (("noise", noise), ("discrepancy", disc)) if used)
    fields = " and ".join(f for f, used in (("noise.prior", noise),
                                            ("discrepancy.sd_prior", disc)) if used)
    points = ("its one observation has" if len(y) == 1
              else f"its {len(y)} observations are equal and have")
    warnings.warn(f"{name}: data set {data.name}: {points} no spread to scale the default "
                  f"{what} prior{'s' if noise and disc else ''} with; they take the sd of "
                  f"{ds.observes} over its simulation runs ({sd:.3g}"
                  f"{' on the log scale' if out.transform == 'log' else ''}) instead; "
                  f"declare {fields} to set {'them' if noise and disc else 'it'}",
                  CalibrationWarning, stacklevel=3)


@partial(jax.jit, static_argnums=(0, 1))
def _fixed_inputs(spec: KOHModel, term: Term, gps, xp, thetas) -> dict:
    """What a term whose inputs have no sampled parameter upstream precomputes: the
    model's inputs ``x_fixed`` (:meth:`KOHModel.inputs`, with the links' ``dx_fixed`` and
    ``corr_fixed`` where it has links), the observed GP at those control inputs
    ``gp_fixed`` (:meth:`ChainPlan.at_controls`) and the discrepancy's squared distances
    per input ``d2u_fixed`` (n, n, q). One compiled program per network and shapes
    (leave-one-out folds and stages share it), instead of the set-up's many small eager
    operations, each of which JAX would compile. XLA's default options, not
    :data:`calnet._jax.FEW_CALLS`: what it returns enters the sampler, whose draws change
    with the last bit of their inputs."""
    x, dx, corr = spec.inputs({"gps": gps}, term, xp, thetas)
    plan = spec.plan
    u = plan.unit_inputs(term.model, x)
    out = {"x_fixed": x, "gp_fixed": plan.at_controls(gps, term.model, term.key, x),
           "d2u_fixed": (u[:, None, :] - u[None]) ** 2}
    if dx is not None:
        out["dx_fixed"], out["corr_fixed"] = dx, corr
    return out


def key_draws(stage: StageResult) -> dict[str, np.ndarray]:
    """Draws (n,) of every parameter sampled in a stage, by key."""
    spec = stage.logdensity.spec
    out = {}
    for var, idx in spec.groups:
        arr = stage.draws(var)
        for j, i in enumerate(idx):
            out[spec.params[i][0]] = arr[:, j]
    return out


# ----------------------------------------------------------------------------- sampling
def _sample(ld: KOHDensity, sampler: SamplerSettings, seed: int,
            progress: Callable[[str], None] | None = None,
            compiled: Callable[[], None] | None = None, warn: bool = True):
    """NUTS on ``ld``; ``progress`` gets plain progress lines (:class:`Lines`); without
    ``warn`` a stuck-chain message goes to the attribute ``stuck_note`` (see
    :func:`_convergence`)."""
    return sample_nuts(ld, seed=seed, num_chains=sampler.chains, num_warmup=sampler.warmup,
                       num_draws=sampler.draws, thin=sampler.thin,
                       target_accept=sampler.target_accept, dense_mass=sampler.dense_mass,
                       chain_method=sampler.chain_method,
                       progress=Lines(ld.name, progress) if progress else False,
                       compiled=compiled, warn=warn)


def calibrate(network: Network, surrogates: Surrogates, *, data=None, mode: str | None = None,
              plug: str | None = None, seed: int | None = None,
              sampler: SamplerSettings | None = None, emulator_variance: bool | None = None,
              progress: Callable[[str], None] | None = None, warn: bool = True,
              compiled: Callable[[], None] | None = None) -> NetworkPosterior:
    """Calibrate every model of ``network`` against its data sets.

    Parameters
    ----------
    network : Network
    surrogates : Surrogates
        A GP for every observed output and every output feeding a link.
    data : mapping of data set name -> ExperimentalData, optional
        Training data (default: the spec's data sets, training split).
    mode : {"segmented", "joint"}, optional
    plug : {"mode", "posterior"}, optional
        Segmented only: hold upstream parameters at their mode, or give the cut posterior.
    seed : int, optional
    sampler : SamplerSettings, optional
    emulator_variance : bool, optional
        Add the surrogates' predictive variance to the likelihood.
    progress : callable, optional
        Called with a message before each stage, and with sampling progress lines (its
        start, one every 10 s, its end).
    warn : bool, default True
        Emit :class:`~calnet.errors.CalibrationWarning` for failed convergence checks
        (R-hat, ESS, divergences) and surrogate checks. ``False`` puts the same messages
        in the posterior's ``notes`` instead (a calibration run beside another one in a
        thread, whose warnings would mix with the other's).
    compiled : callable, optional
        Called with no argument as each stage's sampler is compiled (or found compiled)
        and its chains start: another calibration can then compile beside the chains
        instead of beside this compilation (two compilations at once each take about
        twice as long on 2 cores).

    Returns
    -------
    NetworkPosterior
    """
    cfg = network.settings.calibration
    mode, plug = mode or cfg.mode, plug or cfg.plug
    if mode not in ("segmented", "joint") or plug not in ("mode", "posterior"):
        raise CalibrationError(f"mode must be segmented or joint and plug mode or posterior, "
                               f"got {mode!r} / {plug!r}")
    if mode == "joint" and plug == "mode" and warn:
        warnings.warn("plug 'mode' applies to segmented calibration only: joint mode "
                      "samples every parameter together, so it is ignored",
                      CalibrationWarning, stacklevel=2)
    seed = network.settings.seed if seed is None else seed
    sampler = sampler or network.settings.sampler
    emu = cfg.emulator_variance if emulator_variance is None else emulator_variance
    if data is None:
        data = {k: v.train for k, v in read_all(network).items()}
    if not data:
        return uncalibrated(network, sampler=sampler, seed=seed)
    plan = ChainPlan.from_network(network)
    if mode == "joint":
        post = _joint(network, surrogates, data, plan, seed, sampler, emu, progress, warn,
                      compiled)
    else:
        post = _segmented(network, surrogates, data, plan, seed, sampler, emu, plug, progress,
                          warn, compiled)
    return _checked(network, surrogates, post, warn)


def uncalibrated(network: Network, *, sampler: SamplerSettings | None = None,
                 seed: int = 0) -> NetworkPosterior:
    """The posterior of a network without data: nothing sampled, every parameter keeps its
    prior (``chains * draws / thin`` draws from it, seeded); without parameters it is
    empty (0 draws)."""
    sampler = sampler or network.settings.sampler
    keys = _all_keys(network)
    n = sampler.chains * (sampler.draws // sampler.thin) if keys else 0
    draws = {k: _prior_draws(network, k, n, seed) for k in keys}
    prior_only = tuple(m for m in network.order if network.model(m).parameters)
    return _posterior(network, "none", "-", (), draws, {}, prior_only, {}, ())


def _checked(network, surrogates, post: NetworkPosterior, warn: bool) -> NetworkPosterior:
    """``post`` with its surrogate checks; warns (or, without ``warn``, notes) where a
    surrogate sets the answer, a posterior piles up at a bound, or a convergence check
    failed."""
    checks = tuple(check_surrogates(network, surrogates, post, directions={
        ds: direction_models(network, post, ds) for ds in post.hyper}))
    messages = [c.message() for c in checks if c.message()]
    messages += check_bounds(network, post) + list(post.notes)
    if not warn:
        return replace(post, checks=checks, notes=tuple(messages))
    for message in messages:
        warnings.warn(message, CalibrationWarning, stacklevel=3)
    return replace(post, checks=checks)


def _all_keys(network: Network) -> list[str]:
    return list(dict.fromkeys(k for m in network.order for k in parameter_keys(network, m)))


def _convergence(idata, warn: bool) -> tuple[list[str], PosteriorSummary]:
    """R-hat, ESS and divergence checks of one sampled stage: warned, or (without
    ``warn``) returned as notes; and the stage's diagnostics."""
    summary = summarize(idata, warn=False)
    problems = convergence_problems(summary)
    if not warn:
        notes = [idata.posterior.attrs.get(k) for k in ("stuck_note", "unvisited_note")]
        return [n for n in notes if n] + problems, summary
    for message in problems:
        warnings.warn(message, CalibrationWarning, stacklevel=4)
    return [], summary


def _joint(network, surrogates, data, plan, seed, sampler, emu, progress,
           warn, compiled=None) -> NetworkPosterior:
    free = _all_keys(network)
    models = tuple(m for m in network.order if network.model(m).parameters)
    if progress:
        progress("joint: " + ", ".join(models))
    # named as the stage is in the tables, the netCDF file and run_info.json
    ld = build_koh(network, surrogates, free=free, datasets=data, emulator_variance=emu,
                   name="+".join(models) or "joint", plan=plan)
    if ld.dim == 0:  # no parameters, known noise, no discrepancy: nothing to sample
        return _posterior(network, "joint", "-", (), {}, data, (), {}, ())
    idata = _sample(ld, sampler, seed, progress, compiled, warn)
    problems, diagnostics = _convergence(idata, warn)
    stage = StageResult(models, tuple(data), idata, ld, diagnostics)
    return _posterior(network, "joint", "-", (stage,), key_draws(stage), data, (), {},
                      tuple(problems))


def _owners(network: Network, data) -> dict[str, str]:
    """Key -> the model whose stage calibrates it (segmented): the first model, in
    topological order, with data that the parameter acts on (its own model's, or a model
    downstream of it). A parameter that no data set depends on has no owner."""
    with_data = {network.dataset(k).observed_model for k in data}
    owners: dict[str, str] = {}
    for m in network.order:
        if m in with_data:
            for k in _needed_keys(network, m):
                owners.setdefault(k, m)
    return owners


def stage_keys(network: Network, owners: Mapping[str, str], name: str
               ) -> tuple[list[str], list[str], tuple[str, ...]]:
    """The stage of model ``name`` in segmented mode, with ``owners`` from :func:`_owners`:
    ``(needed, free, models)``, the keys of ``name``'s and its upstream models'
    parameters, those this stage samples, and the models whose parameters it samples
    (upstream ones without data of their own, whose parameters act on this stage's data,
    then ``name``)."""
    needed = _needed_keys(network, name)
    free = [k for k in needed if owners.get(k) == name]
    models = tuple(m for m in network.order if m == name or (
        m in network.ancestors(name) and any(k in free for k in parameter_keys(network, m))))
    return needed, free, models


def segmented_stages(network: Network) -> tuple[list[tuple[tuple[str, ...], list[str]]],
                                                 list[str]]:
    """How segmented mode splits ``network`` with all its data sets: ``(stages, prior)``,
    each stage ``(models, data sets)`` in the order calibrated, and the keys of the
    parameters that keep their prior (no data set depends on them)."""
    data = {d.name: None for d in network.data}
    owners = _owners(network, data)
    stages = []
    for name in network.order:
        own = [d.name for d in network.data if d.observed_model == name]
        if own:
            stages.append((stage_keys(network, owners, name)[2], own))
    prior = list(dict.fromkeys(k for m in network.order for k in parameter_keys(network, m)
                               if k not in owners))
    return stages, prior


def direction_models(network: Network, posterior: NetworkPosterior, dataset: str
                     ) -> tuple[str, ...]:
    """The models whose parameters were sampled with data set ``dataset`` in
    ``posterior`` (the observed model and those upstream of it): what its orthogonal
    discrepancy is orthogonal to (:attr:`~calnet.calibration.koh.Term.directions`), as
    :func:`build_koh` set it when it calibrated the data set."""
    model = network.dataset(dataset).observed_model
    if posterior.mode == "segmented":
        free = stage_keys(network, _owners(network, posterior.data), model)[1]
    else:
        free = _needed_keys(network, model)
    return _models_sampled(network, model, free)


def _models_sampled(network: Network, model: str, free) -> tuple[str, ...]:
    """``model`` and the models upstream of it that have a parameter among the keys
    ``free``, in topological order."""
    return tuple(m for m in (*network.ancestors(model), model)
                 if any(k in free for k in parameter_keys(network, m)))


def _needed_keys(network: Network, model: str) -> list[str]:
    """The parameter keys of ``model`` and of the models upstream of it, in topological
    order (a shared parameter once)."""
    upstream = network.ancestors(model)
    return list(dict.fromkeys(k for m in network.order if m in upstream or m == model
                              for k in parameter_keys(network, m)))


def _segmented(network, surrogates, data, plan, seed, sampler, emu, plug, progress, warn,
               compiled=None):
    stages, draws, prior_only, notes, info = [], {}, [], [], []
    n = sampler.chains * (sampler.draws // sampler.thin)
    owners = _owners(network, data)
    plug_at: dict[str, float] = {}
    for i, name in enumerate(network.order):
        own = {k: v for k, v in data.items() if network.dataset(k).observed_model == name}
        keys = parameter_keys(network, name)
        if not own:
            new = [k for k in keys if k not in draws and k not in owners]
            for k in new:
                draws[k] = _prior_draws(network, k, n, seed)
            if new and not any(k in owners for k in keys):
                prior_only.append(name)
            continue
        # a key is owned by the first stage with data that needs it: the keys this stage
        # holds fixed were sampled by earlier stages
        needed, free, models = stage_keys(network, owners, name)
        fixed_keys = [k for k in needed if k not in free]
        stage_name = "+".join(models)
        for k in fixed_keys:
            if k not in plug_at:
                plug_at[k] = (kde_mode(draws[k]) if plug == "mode"
                              else float(np.mean(draws[k])))
        if progress:
            progress(f"segmented: {stage_name}")
        ld = build_koh(network, surrogates, free=free, datasets=own, emulator_variance=emu,
                       fixed={k: plug_at[k] for k in fixed_keys}, name=stage_name, plan=plan)
        if ld.dim == 0:  # no parameters, known noise, no discrepancy: nothing to sample
            continue
        idata = _sample(ld, sampler, seed + i, progress, compiled, warn)
        problems, diagnostics = _convergence(idata, warn)
        notes += problems
        moved = [k for k in fixed_keys if np.ptp(draws[k]) > 0]
        if plug == "posterior" and moved and ld.dim:
            idata = cut_by_linear_response(ld, idata, {k: draws[k] for k in moved},
                                           {k: plug_at[k] for k in moved})
        else:
            moved = []
        # the diagnostics stay the sampler's (those its warnings gave), also for draws moved
        # by upstream draws: R-hat and ESS of moved draws mix in the upstream stages' draws
        stage = StageResult(models, tuple(own), idata, ld, diagnostics, tuple(moved))
        stages.append(stage)
        draws.update(key_draws(stage))
        for k in free:
            if "." not in k:
                users = [m for m in network.order if k in parameter_keys(network, m)]
                later_models = [f"'{u}'" for u in users if u not in models]
                later = ("" if not later_models else
                         f"; {' and '.join(later_models)} "
                         f"take{'s' if len(later_models) == 1 else ''} its "
                         + ("draws (plug: posterior)" if plug == "posterior"
                            else "posterior mode (plug: mode)"))
                info.append(f"shared parameter '{k}' is calibrated in stage "
                             f"'{stage_name}' with the data of '{name}', the first model "
                             f"with data that it acts on{later} (segmented mode)")
        for m in models[:-1]:
            keys_m = [k for k in parameter_keys(network, m) if k in free and "." in k]
            if keys_m:
                info.append(f"'{m}' has no data of its own: its parameters "
                             f"{[k.split('.', 1)[1] for k in keys_m]} are calibrated in "
                             f"stage '{stage_name}' with the data of '{name}' downstream "
                             "(segmented mode)")
    plugged = {m: np.array([plug_at.get(k, np.nan) for k in parameter_keys(network, m)])
               for m in network.order if any(k in plug_at for k in parameter_keys(network, m))}
    return _posterior(network, "segmented", plug, tuple(stages), draws, data,
                      tuple(prior_only), plugged, tuple(notes), tuple(info))


def _prior_draws(network: Network, key: str, n: int, seed: int) -> np.ndarray:
    """(n,) draws of a parameter's prior (a model without data)."""
    _, p = _parameter(network, key)
    rng = np.random.default_rng([seed, 7919, sum(map(ord, key))])
    return np.asarray(parameter_prior(p).sample(rng, (n,)), dtype=float)


def cut_by_linear_response(ld: KOHDensity, idata, upstream: Mapping[str, np.ndarray],
                           at: Mapping[str, float]):
    """The cut posterior from a stage sampled with upstream parameters fixed at ``at``.

    Each draw ``u^(s)`` (unconstrained) moves by ``J (theta^(s) - at)``, with
    ``J = Cov(u, d loglik / d theta_up)`` over the draws (the linear-response derivative
    of the posterior mean) and ``theta^(s)`` the upstream draws (key -> (N,)). Returns the
    InferenceData with its posterior variables replaced.
    """
    import xarray as xr

    spec = ld.spec
    keys = list(upstream)
    post = idata.posterior
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    u = _unconstrain(ld, {v: np.asarray(post[v].values).reshape((n_chain * n_draw,)
                                                                + post[v].shape[2:])
                          for v in ld.sampled_vars})
    slots = _fixed_slots(ld, keys)
    data = _with_free_inputs(ld.data)
    theta0 = jnp.asarray([at[k] for k in keys])

    def loglik(tf, uu):
        tfixed = dict(data["theta_fixed"])
        for places, v in zip(slots, tf, strict=True):
            for m, j in places:
                tfixed[m] = tfixed[m].at[j].set(v)
        return spec.loglik({**data, "theta_fixed": tfixed}, uu)

    grad = jax.jit(jax.vmap(jax.grad(loglik), in_axes=(None, 0)))
    g = np.asarray(grad(theta0, jnp.asarray(u)))  # (S, F)
    J = (u - u.mean(0)).T @ (g - g.mean(0)) / (len(u) - 1)  # (dim, F)
    S = len(u)
    up = np.column_stack([np.resize(upstream[k], S) for k in keys])
    u_cut = u + (up - np.asarray(theta0)) @ J.T
    values = jax.vmap(lambda uu: spec.constrain(ld.data, uu))(jnp.asarray(u_cut))
    new = {}
    for v in ld.sampled_vars:
        arr = np.asarray(values[v]).reshape((n_chain, n_draw) + np.shape(values[v])[1:])
        new[v] = (post[v].dims, arr)
    idata.posterior = xr.Dataset(new, coords=post.coords, attrs=post.attrs)
    return idata


def _fixed_slots(ld: KOHDensity, keys: list[str]) -> list[list[tuple[str, int]]]:
    """(model, position) in ``theta_fixed`` of each upstream key, for every model that
    uses it (a shared key may sit in several)."""
    return [[(m, ks.index(k)) for m, ks in ld.param_keys.items() if k in ks] for k in keys]


def _with_free_inputs(data: dict) -> dict:
    """``data`` without precomputed inputs, so that they follow ``theta_fixed``."""
    precomputed = ("x_fixed", "dx_fixed", "corr_fixed", "gp_fixed", "d2u_fixed")
    terms = [{k: v for k, v in t.items() if k not in precomputed} for t in data["terms"]]
    return {**data, "terms": terms}


def _unconstrain(ld: KOHDensity, values: Mapping[str, np.ndarray]) -> np.ndarray:
    """Unconstrained positions (S, dim) of constrained posterior draws."""
    spec = ld.spec
    cols = []
    if spec.params:
        params = np.empty((next(iter(values.values())).shape[0], len(spec.params)))
        for var, idx in spec.groups:
            params[:, list(idx)] = values[var].reshape(len(params), -1)
        cols += [np.asarray(prior.to_unconstrained(params[:, i]))
                 for i, (_, prior) in enumerate(spec.params)]
    for term in spec.terms:
        for name, priors in term.blocks():
            v = values[name].reshape(len(values[name]), -1)
            cols += [np.asarray(pr.to_unconstrained(v[:, j])) for j, pr in enumerate(priors)]
    return np.column_stack(cols)


def _posterior(network, mode, plug, stages, draws, data, prior_only, plugged,
               notes, info=()) -> NetworkPosterior:
    n = max((len(v) for v in draws.values()), default=0)
    theta = {m: np.column_stack([np.resize(draws[k], n) for k in parameter_keys(network, m)])
             for m in network.order if network.model(m).parameters}
    hyper: dict = {ds: {} for ds in data}  # {} where nothing of the data set is sampled
    for stage in stages:
        for ds in stage.datasets:
            hyper[ds] = {h: stage.draws(f"{h}_{ds}") for h in ("ell", "sd2", "se2")
                         if f"{h}_{ds}" in stage.idata.posterior}
    attrs = {"+".join(s.models): s.idata.posterior.attrs for s in stages}  # sample_nuts's
    timings = {f"stage_{k}": float(a.get("sampling_time", 0.0)) + float(a.get("compile_time", 0.0))
               for k, a in attrs.items()}
    return NetworkPosterior(mode, plug, stages, theta, hyper, dict(data), prior_only,
                            timings, plugged, notes, info=tuple(info))


def with_stage(post: NetworkPosterior, stage: StageResult,
               data: Mapping[str, ExperimentalData]) -> NetworkPosterior:
    """``post`` with the parameters and hyperparameters a stage sampled replaced by its
    draws (resampled to ``post.n_draws``), calibrated on ``data`` (leave-one-out)."""
    n = post.n_draws
    kd = key_draws(stage)
    theta = {}
    for m, arr in post.theta.items():
        arr = arr.copy()
        for j, k in enumerate(stage.logdensity.param_keys.get(m, ())):
            if k in kd:
                arr[:, j] = np.resize(kd[k], n)
        theta[m] = arr
    hyper = dict(post.hyper)
    for ds in stage.datasets:
        hyper[ds] = {}
        for h in ("ell", "sd2", "se2"):
            if f"{h}_{ds}" in stage.idata.posterior:
                d = stage.draws(f"{h}_{ds}")
                hyper[ds][h] = np.resize(d, (n,) + d.shape[1:])
    return replace(post, theta=theta, hyper=hyper, data={**post.data, **data})
