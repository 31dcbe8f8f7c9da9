"""The surrogates checked against the real simulators where the posterior puts its mass.

Cross-validation says how good a surrogate is over its whole design box; calibration
uses it in the small region the posterior concentrates on, where a handful of design
points may decide it. :func:`verify` goes there: it takes ``k`` posterior draws, pairs
each with one experimental setting of the calibration data, pushes the setting through
the chain to every surrogate's model (upstream surrogates, the draw's parameters), runs
the real simulator at those control inputs and parameters, and compares on the modelled
scale (``ln y`` for ``transform: log``)

    z = (y_sim - m(x, theta)) / s(x, theta),

with ``m`` and ``s`` the GP's predictive mean and sd of a new simulator run (nugget
included). A surrogate agrees when every ``|z| <= 3``.

Where a point's setting is a row of a data set, the simulator's value is also compared
with that row's observation, in sds of the calibration's noise and discrepancy at the
draw (:class:`DataFit`): a surrogate can agree with its simulator where the posterior
is, and the posterior still miss the data (chains that settled in a wrong mode, a
surrogate that led the calibration astray elsewhere). An RMS above :data:`FIT_RMS` says
the simulator at the posterior does not fit the data.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from calnet.calibration.calibrate_network import NetworkPosterior
from calnet.campaign.runners import execute_run, make_simulator, run_timeout
from calnet.chain import ChainPlan
from calnet.errors import CalnetError
from calnet.spec import Network
from calnet.surrogates.fit_network import Surrogates

Z_LIMIT = 3.0
#: an RMS z below this, over at least WIDE_MIN_POINTS points, is noted as an overstated sd
WIDE_RMS_Z = 0.4
WIDE_MIN_POINTS = 8
#: an RMS of the observations' residuals (in the likelihood's sds) above this is a misfit
FIT_RMS = 2.0


@dataclass(frozen=True)
class VerifyPoint:
    """One surrogate output against its simulator at one (draw, setting).

    Attributes
    ----------
    surrogate : str
        ``model.output``.
    point : int
        Index of the (draw, setting) pair, ``0 .. k - 1``.
    draw : int or None
        Row of ``posterior.theta``; None in a network without calibration parameters.
    setting : dict of str to float
        Process inputs (``model.input``) the point was taken at, declared units.
    inputs : dict of str to float
        What the simulator was given: the model's control inputs (through the chain) and
        its parameters (the draw's), declared units.
    status : str
        The run's status (``ok``, ``failed``, ``timeout``, ``nonconverged``); ``failed``
        too when an output modelled on the log scale is not positive.
    message : str
        Why the point is not ``ok`` ("" otherwise).
    simulator, mean, sd, z : float
        Simulator value, surrogate mean and sd on the modelled scale and
        ``(simulator - mean) / sd``; ``simulator`` and ``z`` are NaN unless ``ok``.
    """

    surrogate: str
    point: int
    draw: int | None
    setting: dict[str, float]
    inputs: dict[str, float]
    status: str
    message: str
    simulator: float
    mean: float
    sd: float
    z: float

    def to_dict(self) -> dict:
        return {"surrogate": self.surrogate, "point": self.point, "draw": self.draw,
                "setting": self.setting, "inputs": self.inputs, "status": self.status,
                "message": self.message, "simulator": _num(self.simulator),
                "mean": _num(self.mean), "sd": _num(self.sd), "z": _num(self.z)}


@dataclass(frozen=True)
class SurrogateCheck:
    """Summary of one surrogate over its points.

    Attributes
    ----------
    surrogate : str
    transform : {None, "log"}
        The modelled scale of ``rmse``.
    n : int
        Points compared (simulator ``ok``).
    n_failed : int
        Points whose run did not give a comparable value.
    rmse : float
        Root mean square of ``simulator - mean`` on the modelled scale (NaN when n = 0).
    max_abs_z : float
    share_beyond : float
        Share of the ``n`` points with ``|z| > 3``.
    verdict : str
        ``"agrees"``, or what is wrong and what to do.
    rms_z : float
        Root mean square of ``z``: about 1 where the surrogate's sd states its error.
    note : str
        Empty, or, where at least :data:`WIDE_MIN_POINTS` points have an ``rms_z`` below
        :data:`WIDE_RMS_Z`, that the surrogate's sd overstates its error.
    """

    surrogate: str
    transform: str | None
    n: int
    n_failed: int
    rmse: float
    max_abs_z: float
    share_beyond: float
    verdict: str
    rms_z: float = math.nan
    note: str = ""

    @property
    def agrees(self) -> bool:
        return self.verdict == "agrees"

    def to_dict(self) -> dict:
        return {"surrogate": self.surrogate, "transform": self.transform, "n": self.n,
                "n_failed": self.n_failed, "rmse": _num(self.rmse),
                "max_abs_z": _num(self.max_abs_z), "share_beyond_3sd": _num(self.share_beyond),
                "rms_z": _num(self.rms_z), "verdict": self.verdict, "note": self.note}


@dataclass(frozen=True)
class DataFit:
    """The simulator at posterior points against one data set's observations there.

    Attributes
    ----------
    dataset : str
    observes : str
        ``model.output``.
    n : int
        Points whose setting is a row of the data set and whose run gave a value.
    rms, max_abs : float
        RMS and largest ``|r|``, ``r = (observed - simulator) / sd`` on the modelled
        scale, ``sd`` the calibration's noise and discrepancy sd at the point's draw:
        about 1 where the simulator at the posterior fits the data as the calibration
        says; NaN when ``n`` is 0.
    verdict : str
        ``"fits"``, or what is wrong and what to do.
    noise_sd, discrepancy_sd : float
        RMS over the points of the noise sd and of the discrepancy sd (0 without one)
        the residuals were scaled by, modelled scale.
    rms_noise : float
        RMS of the residuals in sds of the noise alone: whether the simulator needs the
        discrepancy to fit these data.
    """

    dataset: str
    observes: str
    n: int
    rms: float
    max_abs: float
    verdict: str
    noise_sd: float = math.nan
    discrepancy_sd: float = 0.0
    rms_noise: float = math.nan

    @property
    def fits(self) -> bool:
        return self.verdict == "fits"

    def to_dict(self) -> dict:
        return {"dataset": self.dataset, "observes": self.observes, "n": self.n,
                "rms": _num(self.rms), "max_abs": _num(self.max_abs),
                "rms_limit": FIT_RMS, "noise_sd": _num(self.noise_sd),
                "discrepancy_sd": _num(self.discrepancy_sd),
                "rms_noise": _num(self.rms_noise), "verdict": self.verdict}

    def summary(self) -> str:
        """One line for the command line: the verdict, and for a fit how much of the
        scale the discrepancy made (a large discrepancy can hide a model's misfit)."""
        if not self.fits:
            return self.verdict
        text = (f"the simulator fits its observations at the posterior (RMS {self.rms:.2f} "
                f"sds of noise and discrepancy over {self.n} points)")
        if self.discrepancy_sd > 2 * self.noise_sd:
            ratio = (f"a discrepancy {self.discrepancy_sd / self.noise_sd:.0f} times the "
                     f"noise (sd {self.discrepancy_sd:.3g} against {self.noise_sd:.3g})")
            if self.rms_noise <= FIT_RMS:
                text += (f"; it fits within the noise alone too (RMS {self.rms_noise:.2f} "
                         f"noise sds), so these data do not ask for {ratio}: its size "
                         "comes from its prior (few points, or a generous prior)")
            else:
                text += (f", within {ratio}: the model alone misses these data by about "
                         f"that much (RMS {self.rms_noise:.1f} noise sds)")
        return text


@dataclass(frozen=True)
class VerifyResult:
    """Every surrogate checked at ``k`` posterior points.

    Attributes
    ----------
    k, seed : int
    draws : tuple of int or None
        Posterior rows used, one per point.
    points : tuple of VerifyPoint
        Grouped by surrogate, then by point.
    checks : dict of str to SurrogateCheck
        One per surrogate, keyed ``model.output``.
    notes : tuple of str
        How settings were completed where the calibration data did not give them.
    fits : dict of str to DataFit
        Per data set with a row among the points' settings: the simulator against its
        observations.
    """

    k: int
    seed: int
    draws: tuple[int | None, ...]
    points: tuple[VerifyPoint, ...]
    checks: Mapping[str, SurrogateCheck]
    notes: tuple[str, ...] = field(default=())
    fits: Mapping[str, DataFit] = field(default_factory=dict)

    @property
    def agrees(self) -> bool:
        """Whether every surrogate agrees with its simulator."""
        return all(c.agrees for c in self.checks.values())

    def to_dict(self) -> dict:
        return {"k": self.k, "seed": self.seed, "z_limit": Z_LIMIT, "agrees": self.agrees,
                "draws": list(self.draws),
                "checks": {key: c.to_dict() for key, c in self.checks.items()},
                "points": [p.to_dict() for p in self.points], "notes": list(self.notes),
                "data_fits": {name: f.to_dict() for name, f in self.fits.items()}}


def verify(network: Network, surrogates: Surrogates, posterior: NetworkPosterior, *,
           k: int = 8, seed: int = 0, workdir: str | Path,
           progress: Callable[[str], None] | None = None) -> VerifyResult:
    """Run the simulators at ``k`` posterior points and compare every surrogate there.

    Parameters
    ----------
    network : Network
    surrogates : Surrogates
        Every model with a surrogate here is run; upstream outputs that feed a link must
        have one too (the chain evaluates them).
    posterior : NetworkPosterior
        Draws of the parameters and the calibration data (the settings).
    k : int
        Points: posterior draws, each with one setting of the calibration data.
    seed : int
        Picks the draws and the order in which the data rows are cycled through.
    workdir : path
        Folder for the working directories of command simulators (``<workdir>/<model>``).
    progress : callable, optional
        Called with a short message before each model's runs.

    Returns
    -------
    VerifyResult
        A failed run is recorded in its points, never raised.

    Examples
    --------
    >>> result = verify(network, surrogates, posterior, k=8, workdir="out/verify")  # doctest: +SKIP
    >>> result.checks["melt_pool.W"].verdict  # doctest: +SKIP
    'agrees'
    """
    if k < 1:
        raise CalnetError(f"k must be at least 1, got {k}")
    if not surrogates.items:
        raise CalnetError("nothing to verify: no surrogates; run calnet surrogates SPEC "
                          "(or calnet run) first")
    has_parameters = any(m.parameters for m in network.models)
    if posterior.n_draws == 0 and has_parameters:
        raise CalnetError("nothing to verify: the posterior has no draws; run calnet "
                          "calibrate SPEC (or calnet run) first")
    plan = ChainPlan.from_network(network)
    gps = {key: s.gp for key, s in surrogates.items.items()}
    _check_links(plan, gps)
    models = [m for m in network.order if any(s.model == m for s in surrogates.items.values())]
    rng = np.random.default_rng(seed)
    # without parameters a point is a setting only: the posterior has no draws to pick
    draws = (tuple(int(i) for i in rng.choice(posterior.n_draws, size=k,
                                               replace=k > posterior.n_draws))
             if has_parameters else (None,) * k)
    needed = list(dict.fromkeys(key for m in models for key in network.process_input_keys(m)))
    settings, notes, rows = pick_settings(network, posterior.data, needed, k, rng)
    if not has_parameters:
        notes.append("the network has no calibration parameters: each point is a setting "
                      "only, the simulators against the surrogates there")
    points: list[VerifyPoint] = []
    for m in models:
        if progress:
            progress(f"running {m} at {k} posterior points")
        outputs = [s for s in surrogates.items.values() if s.model == m]
        points += _check_model(network, plan, gps, posterior, m, outputs, draws, settings,
                               Path(workdir) / m, progress)
    checks = {s.key: summarise(s.key, s.transform, [p for p in points if p.surrogate == s.key])
              for s in surrogates.items.values() if s.model in models}
    fits = data_fits(network, posterior, points, rows)
    return VerifyResult(k, seed, draws, tuple(points), checks, tuple(notes), fits)


def pick_settings(network: Network, data: Mapping, needed: Sequence[str], k: int,
                  rng: np.random.Generator
                  ) -> tuple[list[dict[str, float]], list[str], list[tuple[str, int] | None]]:
    """``k`` process settings (``model.input -> value``) covering the keys ``needed``,
    notes, and the data row (data set, index) each point's setting starts from (None
    without data).

    Point ``i`` takes row ``i`` (cycling) of a seeded shuffle of every calibration data
    row; keys that row lacks come from a random row of another data set that has them,
    and keys no data set has are drawn within their declared bounds (log-uniform for
    ``scale: log``), with a note saying so.
    """
    rows = [(name, j) for name, d in data.items() for j in range(len(d.x))]
    order = rng.permutation(len(rows))
    unseen = [key for key in needed if not any(key in d.input_keys for d in data.values())]
    settings, sources = [], []
    for i in range(k):
        setting: dict[str, float] = {}
        sources.append(rows[order[i % len(rows)]] if rows else None)
        if rows:
            name, j = sources[-1]
            setting = _row(data[name], j)
        for d in data.values():
            if any(key in needed and key not in setting for key in d.input_keys):
                row = _row(d, int(rng.integers(len(d.x))))
                setting |= {key: v for key, v in row.items() if key not in setting}
        for key in unseen:
            setting[key] = _within_bounds(network, key, rng)
        settings.append({key: setting[key] for key in needed})
    if not data and unseen:
        notes = [f"no data sets: the settings of {unseen} are drawn within their declared "
                 "bounds; add data sets (data: in the spec, then calnet calibrate) to check "
                 "the surrogates at the experiments' settings"]
    else:
        notes = [f"inputs {unseen} appear in no calibration data set; drawn within their "
                 "declared bounds"] if unseen else []
    return settings, notes, sources


def data_fits(network: Network, posterior: NetworkPosterior, points: Sequence[VerifyPoint],
              rows: Sequence[tuple[str, int] | None]) -> dict[str, DataFit]:
    """:class:`DataFit` of every data set that gave a point its setting and whose output
    was run there."""
    from calnet.calibration.terms import known_noise_var, modelled

    by_point = {(p.surrogate, p.point): p for p in points}
    # per data set: its observations on the modelled scale and known noise variances,
    # then one (residual, noise variance, discrepancy variance) per point
    sets = {name: (modelled(network, posterior.data[name]),
                   known_noise_var(network, posterior.data[name]))
            for name in {row[0] for row in rows if row is not None}}
    found: dict[str, list[tuple[float, float, float]]] = {}
    for i, row in enumerate(rows):
        if row is None:
            continue
        name, j = row
        p = by_point.get((posterior.data[name].observes, i))
        if p is None:
            continue
        found.setdefault(name, [])
        observed, known = sets[name]
        hyper = posterior.hyper.get(name, {})
        if p.status != "ok" or (known is None and "se2" not in hyper):
            continue
        noise = float(known[j]) if known is not None else _at(hyper["se2"], p.draw)
        disc = _at(hyper["sd2"], p.draw) if "sd2" in hyper else 0.0
        r = (float(observed[j]) - p.simulator) / math.sqrt(max(noise + disc, 1e-300))
        found[name].append((r, noise, disc))
    warned = {c.dataset for c in posterior.checks if c.message()}
    return {name: _fit(name, posterior.data[name].observes, np.asarray(v).reshape(-1, 3),
                       not network.dataset(name).discrepancy.enabled, name in warned)
            for name, v in found.items()}


def _at(draws: np.ndarray, draw: int | None) -> float:
    """A hyperparameter at a draw (its mean in a network without parameters)."""
    return float(np.mean(draws) if draw is None else draws[draw])


def _fit(name: str, observes: str, found: np.ndarray, no_discrepancy: bool,
         surrogate_warned: bool = False) -> DataFit:
    """``found`` (n, 3): each point's residual in sds, noise and discrepancy variances;
    ``surrogate_warned``: the calibration's surrogate check warned for the data set (the
    surrogates' variance, not the data, set its posterior)."""
    r = found[:, 0]
    if r.size == 0:
        return DataFit(name, observes, 0, math.nan, math.nan,
                       "not checked: no run at its settings gave a value")
    rms, top = float(np.sqrt(np.mean(r**2))), float(np.abs(r).max())
    noise, disc = (float(np.sqrt(np.mean(found[:, c]))) for c in (1, 2))
    # the residuals in sds of the noise alone
    r_noise = r * np.sqrt((found[:, 1] + found[:, 2]) / np.maximum(found[:, 1], 1e-300))
    rms_noise = float(np.sqrt(np.mean(r_noise**2)))
    verdict = "fits" if rms <= FIT_RMS else (
        f"the simulator at the posterior misses these observations: RMS {rms:.1f} sds of "
        f"the calibration's noise and discrepancy over {r.size} points (about 1 for a "
        "fit)" + (": the calibration's surrogate check warned that the surrogates' "
                  "variance, not the data, sets this data set's posterior, which lets it "
                  "stray from the data where the surrogates are uncertain; see that "
                  "warning first (metrics.json, calibration.surrogate_check). Else"
                  if surrogate_warned else ":") + " the model may not describe these data"
        + (" (its spec sets discrepancy: none, so nothing absorbs a model-form error; "
           "the default discrepancy would)" if no_discrepancy else "")
        + "; where the surrogates above agree and calnet run did not warn of a misfit, "
        "the chains may have settled in a wrong mode (run calnet run again with another "
        "seed); where they disagree, the surrogates misled the calibration (more "
        "campaign runs)")
    return DataFit(name, observes, int(r.size), rms, top, verdict, noise, disc, rms_noise)


def summarise(key: str, transform: str | None, points: Sequence[VerifyPoint]) -> SurrogateCheck:
    """The :class:`SurrogateCheck` of one surrogate's points."""
    ok = [p for p in points if p.status == "ok"]
    n, n_failed = len(ok), len(points) - len(ok)
    if n == 0:
        return SurrogateCheck(key, transform, 0, n_failed, math.nan, math.nan, math.nan,
                              f"not checked: none of its {n_failed} simulator runs gave a "
                              "value; see the messages of its points")
    err = np.array([p.simulator - p.mean for p in ok])
    z = np.abs([p.z for p in ok])
    beyond = int(np.sum(z > Z_LIMIT))
    verdict = "agrees" if beyond == 0 else (
        f"surrogate off where the posterior puts its mass: {beyond} of {n} points beyond "
        f"{Z_LIMIT:g} sd; add runs near the posterior")
    rms_z = float(np.sqrt(np.mean(z**2)))
    note = ""
    if n >= WIDE_MIN_POINTS and rms_z < WIDE_RMS_Z:
        ratio = (f"about {1 / rms_z:.0f} times" if rms_z > 1e-3 else
                 "more than 1000 times")
        note = (f"its sd overstates its error {ratio} here "
                f"(RMS z {rms_z:.2f} over {n} points, 1 for a sd that states the error): "
                "predictive bands carry more emulator variance than its real error, and "
                "the emulator's share of a prediction's variance is an upper bound")
    return SurrogateCheck(key, transform, n, n_failed, float(np.sqrt(np.mean(err**2))),
                          float(z.max()), beyond / n, verdict, rms_z, note)


# ----------------------------------------------------------------------------- helpers
def _check_model(network, plan, gps, posterior, model_name, outputs, draws, settings,
                 workdir, progress=None) -> list[VerifyPoint]:
    """Run ``model_name``'s simulator at every point; one VerifyPoint per output and point
    (``progress`` gets a line as each run starts and ends)."""
    model = network.model(model_name)
    sim = make_simulator(network, model, workdir=workdir)
    timeout = run_timeout(network, model)
    expected = tuple(s.output for s in outputs)
    out = {s.key: [] for s in outputs}
    for i, (draw, setting) in enumerate(zip(draws, settings, strict=True)):
        thetas = _thetas(plan, posterior, draw)
        xp = {key: jnp.asarray([v]) for key, v in setting.items()}
        x = plan.inputs(gps, model_name, xp, thetas)
        theta = thetas[model_name]
        inputs = {**dict(zip(model.input_names, np.asarray(x)[0].tolist(), strict=True)),
                  **dict(zip(model.parameter_names, np.asarray(theta).tolist(), strict=True))}
        if progress:
            progress(f"{model_name}: run {i + 1} of {len(settings)} started")
        t0 = time.perf_counter()
        rec = execute_run(sim, i, inputs, timeout, expected)
        if progress:
            progress(f"{model_name}: run {i + 1} of {len(settings)} {rec.status} "
                     f"({time.perf_counter() - t0:.1f} s)")
        z_in = plan.gp_inputs(model_name, x, theta)
        for s in outputs:
            mean, var = (float(np.asarray(a)[0]) for a in s.gp.predict(z_in, include_nugget=True))
            out[s.key].append(_compare(s, i, draw, setting, inputs, rec, mean, math.sqrt(var)))
    return [p for key in out for p in out[key]]


def _compare(sur, i, draw, setting, inputs, rec, mean, sd) -> VerifyPoint:
    status, message, value = rec.status, rec.message, math.nan
    if status == "ok":
        value = float(rec.outputs[sur.output])
        if sur.transform == "log":
            if value > 0:
                value = math.log(value)
            else:
                status, message = "failed", (f"{sur.output} = {value:g} is not positive; it "
                                             "is modelled on the log scale")
                value = math.nan
    z = (value - mean) / sd if sd > 0 else (0.0 if value == mean else math.copysign(
        math.inf, value - mean))
    return VerifyPoint(sur.key, i, draw, dict(setting), dict(inputs), status, message,
                       value, mean, sd, z if status == "ok" else math.nan)


def _thetas(plan: ChainPlan, posterior: NetworkPosterior, draw: int | None) -> dict:
    """Parameter vector of every model at one draw (empty for models without any)."""
    return {m.name: jnp.asarray(posterior.theta[m.name][draw]) if m.name in posterior.theta
            else jnp.zeros(m.n_parameters) for m in plan.models}


def _check_links(plan: ChainPlan, gps: Mapping) -> None:
    missing = sorted({src[2] for m in plan.models for src in m.sources
                      if src[0] == "output" and src[2] not in gps})
    if missing:
        raise CalnetError(f"no surrogate for the linked outputs {missing}; the chain needs "
                          "them: fit surrogates for the whole network (calnet surrogates SPEC)")


def _row(data, j: int) -> dict[str, float]:
    return {key: float(data.x[j, c]) for c, key in enumerate(data.input_keys)}


def _within_bounds(network: Network, key: str, rng: np.random.Generator) -> float:
    model, name = key.split(".", 1)
    var = network.model(model).variable(name)
    if getattr(var, "scale", "linear") == "log":
        return float(np.exp(rng.uniform(np.log(var.lower), np.log(var.upper))))
    return float(rng.uniform(var.lower, var.upper))


def _num(value: float) -> float | None:
    """A float for JSON: NaN and infinities become None."""
    return float(value) if math.isfinite(value) else None
