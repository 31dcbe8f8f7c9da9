"""Save and load a :class:`~calnet.calibration.calibrate_network.NetworkPosterior` without pickle.

What prediction needs is kept: the parameter draws per model, the discrepancy and noise
hyperparameter draws per data set, and the training data each data set was calibrated
on (so a later ``calnet predict`` conditions on exactly the same points even if the CSV
changes). Arrays go to one ``.npz``; names and settings to a JSON file beside it; each
stage's ArviZ posterior is written beside them as netCDF (not read back here).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calnet.calibration.calibrate_network import NetworkPosterior
from calnet.errors import CalibrationError
from calnet.spec import ExperimentalData, Network

FILE = "network_posterior"
FORMAT = 2


def save_posterior(post, folder: str | Path, network: Network | None = None) -> Path:
    """Write ``post`` to ``folder``: each stage's ArviZ posterior as ``<models>.nc`` and
    what prediction needs as ``network_posterior.{npz,json}``; returns the JSON path.
    With the ``network`` it was calibrated for, each data set's noise and discrepancy
    settings are recorded too, and :func:`load_posterior` refuses a spec that changed
    them; the stage files of an earlier calibration of its models in ``folder`` (another
    mode's stages) are removed, so that the folder holds one posterior."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = {f"{'+'.join(stage.models)}.nc" for stage in post.stages}
    for stage in post.stages:
        stage.idata.to_netcdf(str(folder / f"{'+'.join(stage.models)}.nc"))
    if network is not None:  # another mode's stages, from an earlier calibration here
        for path in folder.glob("*.nc"):
            if path.name not in written and set(path.stem.split("+")) <= set(network.order):
                path.unlink()
    arrays: dict[str, np.ndarray] = {}
    for model, draws in post.theta.items():
        arrays[f"theta/{model}"] = np.asarray(draws, float)
    for ds, hyper in post.hyper.items():
        for h, v in hyper.items():
            arrays[f"hyper/{ds}/{h}"] = np.asarray(v, float)
    data_meta = {}
    for ds, d in post.data.items():
        arrays[f"data/{ds}/x"] = np.asarray(d.x, float)
        arrays[f"data/{ds}/y"] = np.asarray(d.y, float)
        if d.noise_sd is not None:
            arrays[f"data/{ds}/noise_sd"] = np.asarray(d.noise_sd, float)
        data_meta[ds] = {"observes": d.observes, "input_keys": list(d.input_keys),
                         "labels": list(d.labels)}
        if network is not None:
            data_meta[ds]["settings"] = _term_settings(network, ds)
    for model, values in post.plugged.items():
        arrays[f"plugged/{model}"] = np.asarray(values, float)
    np.savez_compressed(folder / f"{FILE}.npz", **arrays)
    meta = {"format": FORMAT, "mode": post.mode, "plug": post.plug,
            **({"spec": _spec_settings(network)} if network is not None else {}),
            "prior_only": list(post.prior_only), "models": list(post.theta),
            "hyper": {ds: list(h) for ds, h in post.hyper.items()},
            "data": data_meta,
            "plugged": list(post.plugged), "notes": list(post.notes),
            "info": list(post.info),
            "timings": dict(post.timings)}
    path = folder / f"{FILE}.json"
    path.write_text(json.dumps(meta, indent=1))
    return path


def load_posterior(folder: str | Path, network: Network | None = None):
    """Read a posterior written by :func:`save_posterior`.

    ``network``, when given, is checked against it: every model and data set of the
    posterior must exist with the same number of parameters and inputs.
    """
    folder = Path(folder)
    meta_path, npz_path = folder / f"{FILE}.json", folder / f"{FILE}.npz"
    if not meta_path.is_file() or not npz_path.is_file():
        raise CalibrationError(
            f"no calibrated posterior in '{folder}' (expected {FILE}.json and {FILE}.npz); "
            "run 'calnet calibrate SPEC' or 'calnet run SPEC' first, or point --run at the "
            "folder they wrote")
    meta = json.loads(meta_path.read_text())
    if meta.get("format") != FORMAT:
        raise CalibrationError(f"'{meta_path}' has format {meta.get('format')!r}; this "
                               f"calnet reads format {FORMAT}; calibrate again")
    with np.load(npz_path) as z:
        arrays = {k: z[k] for k in z.files}
    theta = {m: arrays[f"theta/{m}"] for m in meta["models"]}
    hyper = {ds: {h: arrays[f"hyper/{ds}/{h}"] for h in hs} for ds, hs in meta["hyper"].items()}
    data = {}
    for ds, dm in meta["data"].items():
        y = arrays[f"data/{ds}/y"]
        data[ds] = ExperimentalData(ds, dm["observes"], tuple(dm["input_keys"]),
                                    arrays[f"data/{ds}/x"], y, np.zeros(len(y), bool),
                                    tuple(dm["labels"]), arrays.get(f"data/{ds}/noise_sd"))
    plugged = {m: arrays[f"plugged/{m}"] for m in meta["plugged"]}
    post = NetworkPosterior(meta["mode"], meta["plug"], (), theta, hyper, data,
                            tuple(meta["prior_only"]), meta.get("timings", {}), plugged,
                            tuple(meta["notes"]), info=tuple(meta.get("info", ())))
    if network is not None:
        _check_spec(meta.get("spec"), network, folder)
        _check_matches(post, network, folder, meta["data"])
    return post


_DESCRIBED = {"__all__": {"description"}}


def _spec_settings(network: Network) -> dict:
    """What of the spec a posterior depends on, as JSON: each model's inputs, parameters
    (bounds, priors, sharing) and outputs (transforms), and the links. Not the
    simulators, campaigns or surrogate settings: the surrogates saved beside the
    posterior stand in for them."""
    parts = {"inputs", "parameters", "outputs"}
    return {"models": {m.name: m.model_dump(mode="json", include=parts,
                                            exclude={k: _DESCRIBED for k in parts})
                       for m in network.models},
            "links": sorted(f"{ln.source} -> {ln.target}" for ln in network.links)}


def _check_spec(then: dict | None, network: Network, folder: Path) -> None:
    """Refuse a spec whose models or links differ from those the posterior in ``folder``
    was calibrated with (``then``, recorded by :func:`save_posterior`; None for a
    posterior saved without its network, which is not checked here)."""
    if then is None:
        return
    now = _spec_settings(network)
    changed = []
    if then["links"] != now["links"]:
        changed.append(f"the links ({', '.join(then['links']) or 'none'} there)")
    for name in sorted(set(then["models"]) | set(now["models"])):
        a, b = then["models"].get(name), now["models"].get(name)
        if a is None or b is None:
            changed.append(f"model '{name}' ({'not in this spec' if b is None else 'new'})")
        elif a != b:
            changed.append(f"model '{name}' ({', '.join(k for k in a if a[k] != b.get(k))})")
    if changed:
        raise CalibrationError(
            f"the posterior in '{folder}' was calibrated with another spec: "
            + "; ".join(changed) + " differ; calibrate again with this spec, or use the "
            "spec it was calibrated with")


def _settings_change(network: Network, dataset: str, then: dict) -> str:
    """``noise sd sampled, ... there; noise sd 0.05 (known) here``: a data set's noise and
    discrepancy as calibrated and as this spec gives them, in words."""
    from calnet.spec.models import DiscrepancySettings, NoiseSettings

    ds = network.dataset(dataset)
    try:
        before = network.term_text(ds, NoiseSettings.model_validate(then["noise"]),
                                   DiscrepancySettings.model_validate(then["discrepancy"]))
    except (KeyError, ValueError):  # written by another version: the fields themselves
        now = _term_settings(network, dataset)
        return "; ".join(_differences(k, then.get(k), now[k]) for k in now
                         if then.get(k) != now[k])
    return f"{before} there; {network.term_text(ds)} here"


def _differences(name: str, then, now) -> str:
    """``noise.sd 0.02 there, none here``: the fields of a setting that differ."""
    if isinstance(then, dict) and isinstance(now, dict):
        keys = [k for k in {**then, **now} if then.get(k) != now.get(k)]
        return "; ".join(f"{name}.{k} {_plain(then.get(k))} there, {_plain(now.get(k))} here"
                         for k in keys)
    return f"{name} {_plain(then)} there, {_plain(now)} here"


def _plain(value) -> str:
    return "none" if value is None else str(value)


def _term_settings(network: Network, dataset: str) -> dict:
    """A data set's noise and discrepancy settings, as JSON: with the data, they make its
    KOH term, so a posterior predicts only under the settings it was calibrated with."""
    ds = network.dataset(dataset)
    return {"noise": ds.noise.model_dump(mode="json"),
            "discrepancy": ds.discrepancy.model_dump(mode="json")}


def _check_matches(post, network: Network, folder: Path, data_meta: dict) -> None:
    names = {m.name for m in network.models}
    for model, draws in post.theta.items():
        if model not in names or draws.shape[1] != len(network.model(model).parameters):
            raise CalibrationError(
                f"the posterior in '{folder}' does not fit this spec (model '{model}' is "
                "missing or has other parameters); calibrate again")
    for ds, d in post.data.items():
        try:
            spec_ds = network.dataset(ds)
        except KeyError:
            raise CalibrationError(f"the posterior in '{folder}' was calibrated on data set "
                                   f"'{ds}', which this spec does not declare; calibrate "
                                   "again") from None
        keys = network.process_input_keys(spec_ds.observed_model)
        if list(d.input_keys) != keys or d.observes != spec_ds.observes:
            raise CalibrationError(f"the posterior in '{folder}': data set '{ds}' has inputs "
                                   f"{list(d.input_keys)} but the spec gives {keys}; "
                                   "calibrate again")
    differ = []  # every data set whose noise or discrepancy settings changed
    for ds in post.data:
        then = data_meta.get(ds, {}).get("settings")
        now = _term_settings(network, ds)
        changed = [k for k in now if then is not None and then.get(k) != now[k]]
        if changed:
            differ.append(f"{' and '.join(changed)} settings for data set '{ds}' ("
                          + _settings_change(network, ds, then) + ")")
    if differ:
        raise CalibrationError(
            f"the posterior in '{folder}' was calibrated with other " + ", and other ".join(
                differ) + "; calibrate again with this spec, or use the spec it was "
            "calibrated with")
