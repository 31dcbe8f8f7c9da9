"""Fit every surrogate a network needs from its campaign stores (method.md section 2).

One GP per needed output (observed by a data set, feeding a link or listed in
``settings.predict``), trained on the model's ok runs over its inputs and parameters.
Inputs declared ``scale: log`` enter the GP as ``ln x``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from calnet.campaign import load_runs
from calnet.errors import SurrogateError
from calnet.files import make_folder, replacing
from calnet.parallel import map_threads
from calnet.spec import Network
from calnet.surrogates.cv import CVResult, check_folds, cross_validate
from calnet.surrogates.fit import fit_gp
from calnet.surrogates.gp import FittedGP
from calnet.surrogates.persist import load_gp, save_gp
from calnet.surrogates.space import gp_bounds, gp_space


@dataclass(frozen=True)
class OutputSurrogate:
    """The fitted GP of one model output, with its cross-validation and provenance."""

    model: str
    output: str
    gp: FittedGP
    cv: CVResult | None
    n_runs: int
    n_excluded: int

    @property
    def key(self) -> str:
        return f"{self.model}.{self.output}"

    @property
    def transform(self) -> str | None:
        return self.gp.transform

    def summary(self) -> dict:
        """JSON-ready metrics (for ``metrics.json``)."""
        doc = {"model": self.model, "output": self.output, "transform": self.transform,
               "mean": self.gp.mean, "n_runs": self.n_runs, "n_excluded": self.n_excluded,
               "nlml": float(self.gp.nlml) if self.gp.nlml is not None else None}
        if self.cv is not None:
            doc["cv"] = self.cv.metrics()
        return doc


@dataclass(frozen=True)
class Surrogates:
    """All surrogates of a network, keyed by ``model.output``."""

    items: Mapping[str, OutputSurrogate] = field(default_factory=dict)

    def __getitem__(self, key: str) -> OutputSurrogate:
        return self.items[key]

    def __contains__(self, key: str) -> bool:
        return key in self.items

    def gp(self, model: str, output: str) -> FittedGP:
        try:
            return self.items[f"{model}.{output}"].gp
        except KeyError:
            raise SurrogateError(f"no surrogate for '{model}.{output}'; fit surrogates "
                                 "for this network first (calnet surrogates SPEC)") from None

    def summary(self) -> dict:
        return {k: s.summary() for k, s in self.items.items()}

    def save(self, folder: str | Path) -> Path:
        """Write every GP (``.npz`` + JSON, no pickle) and an index to ``folder``."""
        folder = make_folder(folder)
        index = {}
        for key, s in self.items.items():
            save_gp(s.gp, folder / key)
            index[key] = {**s.summary(), "file": key}
        with replacing(folder / "surrogates.json") as tmp:
            tmp.write_text(json.dumps(index, indent=2, default=float))
        return folder

    @classmethod
    def load(cls, folder: str | Path) -> Surrogates:
        """Read surrogates written by :meth:`save` (CV results are not reloaded)."""
        folder = Path(folder)
        index_path = folder / "surrogates.json"
        if not index_path.is_file():
            raise SurrogateError(f"{folder}: no surrogates.json; run calnet surrogates first")
        index = json.loads(index_path.read_text())
        return cls({k: OutputSurrogate(v["model"], v["output"], load_gp(folder / v["file"]),
                                       None, v["n_runs"], v["n_excluded"])
                    for k, v in index.items()})


def check_surrogates(network: Network, surrogates: Surrogates, where: str | Path) -> None:
    """Raise :class:`~calnet.errors.SurrogateError` unless ``surrogates`` (read from
    ``where``) hold a GP for every output ``network`` needs, each on that model's inputs
    and parameters, and nothing for outputs the network does not have."""
    needed = {f"{m}.{o.name}": len(network.model(m).inputs) + len(network.model(m).parameters)
              for m in network.order for o in network.needed_outputs(m)}
    missing = [k for k in needed if k not in surrogates.items]
    foreign = [k for k in surrogates.items
               if k.split(".")[0] not in network.order
               or k.split(".", 1)[1] not in network.model(k.split(".")[0]).output_names]
    other = [k for k, n in needed.items()
             if k in surrogates.items and surrogates.items[k].gp.n_inputs != n]
    if missing or foreign or other:
        what = "; ".join(x for x in (
            f"no GP for {missing}" if missing else "",
            f"GPs of outputs the network does not have {foreign}" if foreign else "",
            f"GPs on other inputs for {other}" if other else "") if x)
        raise SurrogateError(f"the surrogates in '{where}' were not fitted for network "
                             f"'{network.name}' ({what}); fit them with 'calnet surrogates' "
                             "or 'calnet run' on this spec, or pass the folder of its run")


@dataclass(frozen=True)
class _Job:
    """One output to fit: its training data, :func:`fit_gp`'s keywords and the folds."""

    model: str
    output: str
    x: np.ndarray
    y: np.ndarray
    kw: dict
    folds: int
    n_excluded: int


def _jobs(network: Network, stores, seed: int, restarts: int | None,
          cv_folds: int | None) -> list[_Job]:
    jobs = []
    for name in network.order:
        model = network.model(name)
        needed = network.needed_outputs(name)
        if not needed:
            continue
        settings = model.surrogate or network.settings.surrogate
        runs = load_runs(network, name, store=(stores or {}).get(name))
        x = gp_space(model, np.asarray(runs.X, dtype=float))
        lower, upper = gp_bounds(model)
        for out in needed:
            y = np.asarray(runs.Y[out.name], dtype=float)
            ok = np.isfinite(y) & np.all(np.isfinite(x), axis=1)
            if ok.sum() == 0:
                raise SurrogateError(f"{name}.{out.name}: all {runs.n_total} runs failed or "
                                     "gave non-finite values; fix the simulator, then run "
                                     f"them again: calnet campaign SPEC --model {name} "
                                     "--retry-failed (or calnet run SPEC --fresh)")
            _enough_runs(name, out.name, int(ok.sum()), runs.n_total, x.shape[1])
            kw = dict(lower=lower, upper=upper, transform=out.transform,
                      n_restarts=min(restarts or settings.restarts, settings.restarts),
                      seed=seed, name=f"{name}.{out.name}", mean=settings.mean)
            folds = min(cv_folds or settings.cv_folds, settings.cv_folds, int(ok.sum()))
            jobs.append(_Job(name, out.name, x[ok], y[ok], kw, folds,
                             runs.n_excluded + int((~ok).sum())))
    return jobs


def _enough_runs(model: str, output: str, n_ok: int, n_total: int, d: int) -> None:
    """Raise :class:`~calnet.errors.SurrogateError` unless ``n_ok`` runs (of ``n_total``)
    are enough for a GP on ``d`` inputs and parameters: ``d + 2``."""
    need = d + 2
    if n_ok >= need:
        return
    more = f"calnet campaign SPEC --model {model} --runs N (N > {n_total})"
    fix = (f"run more simulations: {more}" if n_ok == n_total else
           f"fix the simulator and run the others again (calnet campaign SPEC --model "
           f"{model} --retry-failed), or run more simulations: {more}")
    raise SurrogateError(f"{model}.{output}: {n_ok} of the {n_total} runs of '{model}' "
                         f"finished ok with a finite value, and a surrogate needs at "
                         f"least {need} (its inputs and parameters, {d}, plus 2); {fix}")


def _cross_validate(job: _Job, gp: FittedGP, before_fold=None) -> CVResult:
    # folds re-optimise from the full-data optimum (one start each): k refits at the cost
    # of about k / (restarts + 1) full fits
    # with the full fit's mean function ("auto" chose it once, on all the runs)
    return cross_validate(job.x, job.y, k=job.folds,
                          **{**job.kw, "n_restarts": 0, "mean": gp.mean},
                          init=np.asarray(gp.log_params), before_fold=before_fold)


def fit_surrogates(network: Network, *, stores: Mapping[str, Path] | None = None,
                   seed: int | None = None, cv: bool = True, restarts: int | None = None,
                   cv_folds: int | None = None,
                   progress: Callable[[str], None] | None = None) -> Surrogates:
    """Fit (and cross-validate) a GP for every output the network needs.

    Parameters
    ----------
    network : Network
    stores : mapping of model name to campaign store path, optional
        Defaults to each model's default store beside the spec.
    seed : int, optional
        Seeds optimiser restarts and CV folds (default: ``network.settings.seed``).
    cv : bool
        Run k-fold cross-validation (k from the model's or the network's settings).
        Without it, :func:`cross_validate_surrogates` adds the same cross-validation
        later (``calnet run`` runs it beside the calibration).
    restarts, cv_folds : int, optional
        Caps on the spec's surrogate settings (e.g. for a quick run): at most this many,
        never more than the spec asks for.
    progress : callable, optional
        Called with a short message before each fit.

    Returns
    -------
    Surrogates
    """
    seed = network.settings.seed if seed is None else seed
    jobs = _jobs(network, stores, seed, restarts, cv_folds)
    if cv:  # before any fit: the folds' runs against the mean functions' coefficients
        check_cross_validation(network, stores=stores, cv_folds=cv_folds)

    def fit(job: _Job) -> OutputSurrogate:
        if progress:
            progress(f"{job.model}.{job.output}")
        gp = fit_gp(job.x, job.y, **job.kw)
        cvr = _cross_validate(job, gp) if cv and job.folds else None
        return OutputSurrogate(job.model, job.output, gp, cvr, len(job.y), job.n_excluded)

    items = {s.key: s for s in map_threads(fit, jobs)}  # outputs side by side
    return Surrogates(items)


def check_cross_validation(network: Network, *, stores: Mapping[str, Path] | None = None,
                           cv_folds: int | None = None) -> None:
    """Raise :class:`~calnet.errors.SurrogateError` where :func:`cross_validate_surrogates`
    would: an output with too few ok runs for its folds."""
    for job in _jobs(network, stores, 0, None, cv_folds):
        if job.folds:
            check_folds(job.folds, *job.x.shape, name=job.kw["name"], mean=job.kw["mean"])


def cross_validate_surrogates(network: Network, surrogates: Surrogates, *,
                              stores: Mapping[str, Path] | None = None,
                              seed: int | None = None, cv_folds: int | None = None,
                              before_fold: Callable[[], None] | None = None) -> Surrogates:
    """``surrogates`` (fitted by :func:`fit_surrogates` with ``cv=False`` and the same
    ``stores`` and ``seed``) with the k-fold cross-validation that :func:`fit_surrogates`
    would have given them: the same folds, starts and results, one output after another
    in the calling thread. ``before_fold`` is called before each fold (see
    :func:`calnet.surrogates.cv.cross_validate`)."""
    seed = network.settings.seed if seed is None else seed
    items = dict(surrogates.items)
    for job in _jobs(network, stores, seed, None, cv_folds):
        key = f"{job.model}.{job.output}"
        if job.folds and key in items:
            items[key] = replace(items[key], cv=_cross_validate(job, items[key].gp,
                                                                before_fold))
    return Surrogates(items)
