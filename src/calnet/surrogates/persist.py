"""Save and load a :class:`FittedGP`: an ``.npz`` of arrays plus a JSON sidecar, no pickle.

``gp.save("out/W.npz")`` writes ``out/W.npz`` (every array field, float64, bit-exact) and
``out/W.json`` (format version, transform, name, shapes, and the scalars again for people
to read). :func:`load_gp` reads the arrays with ``allow_pickle=False`` and checks them
against the sidecar.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from calnet.errors import SurrogateError
from calnet.files import make_folder, replacing
from calnet.surrogates.gp import ARRAY_FIELDS, TREND_FIELDS, FittedGP, constant_mean
from calnet.surrogates.likelihood import MEANS, n_basis

FORMAT = "calnet.FittedGP"
#: version 2 adds the mean function's arrays; version 1 files (constant mean) still load
VERSION = 2
READABLE = (1, 2)


def _paths(path: str | Path) -> tuple[Path, Path]:
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    return path, path.with_suffix(".json")


def save_gp(gp: FittedGP, path: str | Path) -> Path:
    """Write ``gp`` to ``path`` (``.npz``, suffix added if missing) and a ``.json`` sidecar.

    Parameters
    ----------
    gp : FittedGP
    path : str or Path

    Returns
    -------
    Path
        The ``.npz`` path written.

    Raises
    ------
    CalnetError
        When a file cannot be written (no space left, read-only); each file is replaced
        whole or left as it was.
    """
    npz, sidecar = _paths(path)
    make_folder(npz.parent)
    arrays = {f: np.asarray(getattr(gp, f), dtype=np.float64) for f in ARRAY_FIELDS}
    with replacing(npz) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "name": gp.name,
        "transform": gp.transform,
        "n_train": gp.n_train,
        "n_inputs": gp.n_inputs,
        "arrays": sorted(arrays),
        "lengthscales": arrays["lengthscales"].tolist(),
        "signal_var": float(arrays["signal_var"]),
        "nugget": float(arrays["nugget"]),
        "nlml": float(arrays["nlml"]),
        "mean": gp.mean,
        "lower": arrays["lower"].tolist(),
        "upper": arrays["upper"].tolist(),
    }
    with replacing(sidecar) as tmp:
        tmp.write_text(json.dumps(meta, indent=2, allow_nan=True) + "\n")
    return npz


def load_gp(path: str | Path) -> FittedGP:
    """Read a surrogate written by :func:`save_gp`.

    Raises
    ------
    SurrogateError
        When either file is missing, is not a calnet surrogate, or the arrays do not
        match the sidecar.
    """
    npz, sidecar = _paths(path)
    for p in (npz, sidecar):
        if not p.is_file():
            raise SurrogateError(f"{p}: surrogate file not found; write it with gp.save()")
    meta = json.loads(sidecar.read_text())
    if meta.get("format") != FORMAT or meta.get("version") not in READABLE:
        raise SurrogateError(f"{sidecar}: not a {FORMAT} sidecar of version "
                             f"{' or '.join(map(str, READABLE))}; refit and save the surrogate "
                             "with this calnet version")
    n, d = meta["n_train"], meta["n_inputs"]
    need = ARRAY_FIELDS if meta["version"] >= 2 else tuple(
        f for f in ARRAY_FIELDS if f not in TREND_FIELDS)
    with np.load(npz, allow_pickle=False) as data:
        missing = [f for f in need if f not in data.files]
        if missing:
            raise SurrogateError(f"{npz}: arrays {missing} missing; refit and save again")
        arrays = {f: jnp.asarray(data[f]) for f in need}
    arrays = {**constant_mean(n), **arrays}
    p = arrays["beta"].shape[0] if arrays["beta"].ndim == 1 else -1
    if (arrays["x_train"].shape != (n, d) or arrays["chol"].shape != (n, n)
            or p not in {n_basis(m, d) for m in MEANS}
            or arrays["basis_solve"].shape != (n, p) or arrays["basis_chol"].shape != (p, p)):
        raise SurrogateError(f"{npz}: array shapes do not match {sidecar.name} "
                             f"(n_train={n}, n_inputs={d}); the pair is inconsistent")
    return FittedGP(**arrays, transform=meta["transform"], name=meta["name"])
