"""Experimental data sets: read, check and hand out as arrays."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from calnet.errors import SpecError, SpecWarning
from calnet.spec.models import Dataset
from calnet.spec.network import Network


@dataclass(frozen=True)
class ExperimentalData:
    """One data set as arrays.

    Attributes
    ----------
    name : str
    observes : str
        ``model.output`` observed.
    input_keys : tuple of str
        ``model.input`` of each column of ``x`` (the process inputs, topological order).
    x : ndarray, shape (n_points, n_inputs)
        Process inputs in their declared units.
    y : ndarray, shape (n_points,)
        Observations in the output's declared unit.
    is_test : ndarray of bool, shape (n_points,)
        True for rows held out by the split column.
    labels : tuple of str
        Row labels (the CSV's first column, or the row number).
    noise_sd : ndarray, shape (n_points,), or None
        Known measurement sd of each observation in the output's unit (``noise: sd`` or
        ``noise: sd_column``); None when the noise is unknown.
    """

    name: str
    observes: str
    input_keys: tuple[str, ...]
    x: np.ndarray
    y: np.ndarray
    is_test: np.ndarray
    labels: tuple[str, ...]
    noise_sd: np.ndarray | None = None

    @property
    def train(self) -> ExperimentalData:
        return self.subset(~self.is_test)

    @property
    def test(self) -> ExperimentalData:
        return self.subset(self.is_test)

    def subset(self, mask: np.ndarray) -> ExperimentalData:
        """Rows selected by a boolean mask or an index array."""
        idx = np.arange(len(self.y))[mask]
        return ExperimentalData(self.name, self.observes, self.input_keys, self.x[idx],
                                self.y[idx], self.is_test[idx],
                                tuple(self.labels[i] for i in idx),
                                None if self.noise_sd is None else self.noise_sd[idx])


def read_dataset(network: Network, ds: Dataset) -> ExperimentalData:
    """Read and check one data set of ``network``; raise :class:`SpecError` on bad data.

    Points outside the models' input bounds give a :class:`SpecWarning` with their count,
    or a :class:`SpecError` when ``strict`` (data set or settings) is on.
    """
    import pandas as pd

    path = network.path(ds.path)
    field = f"data.{ds.name}"
    if not path.is_file():
        raise SpecError(f"data file '{path}' not found; fix 'path' (relative paths are "
                        "resolved against the spec's folder)", file=network.source or None,
                        field=f"{field}.path")
    try:
        frame = pd.read_csv(path)
    except Exception as err:  # pandas raises many kinds; all mean an unreadable CSV
        raise SpecError(f"cannot read '{path}' as CSV ({err})", file=str(path),
                        field=field) from None
    if frame.empty:
        raise SpecError("the CSV has a header but no data rows; add the measurements",
                        file=str(path), field=field)
    twice = repeated_header(path)
    if twice:
        raise SpecError(f"column '{twice}' appears twice in the header; give each column its "
                        "own name", file=str(path), field=field)
    wanted = network.process_input_keys(ds.observed_model)
    resolved = network.dataset_columns(ds)
    absent = [resolved[k] for k in (*wanted, ds.observes) if resolved[k] not in frame.columns]
    if ds.columns is None and absent:
        raise SpecError(f"no column {absent} (it has {list(frame.columns)}); without "
                        "'columns' each input and the observed output are read from the "
                        "column of their own name: rename the columns, or add 'columns: "
                        "{variable: <csv column>, ...}'", file=str(path), field=field)
    if ds.columns is None:
        _warn_linked_columns(network, ds, frame.columns, set(resolved.values()), path)
    columns, problems = {}, []
    for key in (*wanted, ds.observes):  # every column's problem, not only the first's
        try:
            columns[key] = _numeric_column(frame, resolved[key], path, field)
        except SpecError as err:
            problems.append(err)
    if problems:
        raise SpecError(problems[0].reason, file=str(path), field=problems[0].field,
                        more=[e.reason for e in problems[1:]])
    x = np.column_stack([columns[k] for k in wanted]) if wanted else np.empty((len(frame), 0))
    y = columns[ds.observes]
    out = network.observed(ds)
    if out.transform == "log" and np.any(y <= 0):
        rows = (np.flatnonzero(y <= 0) + 2).tolist()
        raise SpecError(f"column '{resolved[ds.observes]}' has {len(rows)} value(s) <= 0 on "
                        f"line(s) {rows[:10]}, but '{ds.observes}' is modelled on the log "
                        "scale (transform: log); remove those rows or drop the transform",
                        file=str(path), field=f"{field}.columns")
    is_test = _split_mask(frame, ds, path, field)
    labels = tuple(str(v) for v in frame.iloc[:, 0]) if len(frame.columns) else ()
    noise_sd = _noise_sd(frame, ds, path, field)
    data = ExperimentalData(ds.name, ds.observes, tuple(wanted), x, y, is_test, labels,
                            noise_sd)
    data = _once(data, _repeats(_rows(data)), f"{ds.path}: {field}")
    _check_bounds(network, ds, wanted, data.x, path, field)  # the rows that count
    _check_spread(ds, wanted, data.x, field)
    return data


def _warn_linked_columns(network: Network, ds: Dataset, names, used: set[str], path) -> None:
    """Warn of CSV columns named like a linked input of the observed model or a model
    upstream of it: the network computes such an input, so a measured value of it in the
    data set is not read (a user may expect it to be)."""
    unread = []
    for m in (*network.ancestors(ds.observed_model), ds.observed_model):
        for v in network.model(m).inputs:
            link = network.link_into(m, v.name)
            if link is not None and v.name in names and v.name not in used:
                unread.append(f"'{v.name}' ({m}.{v.name} is linked from {link.source})")
    if unread:
        warnings.warn(f"{ds.path}: data.{ds.name}: column{'s' if len(unread) > 1 else ''} "
                      f"{', '.join(unread)} not read: the network computes linked inputs "
                      "from the models upstream; remove the column, or the link to set the "
                      "input from the data", SpecWarning, stacklevel=3)


def _check_spread(ds: Dataset, keys: list[str], x: np.ndarray, field: str) -> None:
    """Warn of a process input that the data set's points never vary: the data then see
    the model at one value of it, and what acts through that input cannot be told apart
    from what does not (the sensitivity takes the input's declared bounds instead)."""
    if len(x) < 2:
        return
    same = [f"{key} = {x[0, j]:g}" for j, key in enumerate(keys) if np.all(x[:, j] == x[0, j])]
    if same:
        warnings.warn(f"{ds.path}: {field}: all {len(x)} points have {', '.join(same)}: the "
                      "data inform the model at that setting only, so parameters that act "
                      "through it cannot be told apart there; vary it across the experiments "
                      "if it matters", SpecWarning, stacklevel=3)


def repeated_header(path) -> str | None:
    """The first column name that ``path``'s CSV header holds twice, else None (pandas
    would rename the second ``P`` to ``P.1``)."""
    import csv

    with open(path, newline="") as fh:
        header = [h.strip() for h in next(csv.reader(fh), [])]
    return next((h for i, h in enumerate(header) if h in header[:i]), None)


def _rows(data: ExperimentalData) -> list[tuple]:
    """Each row's settings, observation, split and known noise sd: what makes it a
    measurement."""
    sd = [None] * len(data.y) if data.noise_sd is None else data.noise_sd.tolist()
    return [(*data.x[i].tolist(), float(data.y[i]), bool(data.is_test[i]), sd[i])
            for i in range(len(data.y))]


def _repeats(rows: list[tuple]) -> dict[int, str]:
    """``{row index: the earlier row it repeats}`` for the rows equal to an earlier one."""
    first: dict[tuple, int] = {}
    out = {}
    for i, row in enumerate(rows):
        j = first.setdefault(row, i)
        if j != i:
            out[i] = f"line {i + 2} repeats line {j + 2}"
    return out


def _settings(data: ExperimentalData, i: int) -> str:
    """Row ``i``'s inputs and value, ``"x=0.3, y=1.2"``."""
    names = [k.split(".", 1)[1] for k in data.input_keys] + [data.observes.split(".")[1]]
    values = [*data.x[i].tolist(), float(data.y[i])]
    return ", ".join(f"{n}={v:g}" for n, v in zip(names, values, strict=True))


def _once(data: ExperimentalData, repeats: dict[int, str], where: str) -> ExperimentalData:
    """``data`` without the rows ``repeats`` (a SpecWarning names them): a measurement
    given twice would count twice in the likelihood."""
    if not repeats:
        return data
    pairs = [f"{_settings(data, i)} ({first})" for i, first in repeats.items()]
    shown = "; ".join(pairs[:5]) + ("; ..." if len(pairs) > 5 else "")
    warnings.warn(f"{where}: {len(pairs)} row(s) repeat an earlier measurement (inputs, "
                  f"value and split): {shown}; each is kept once, so that it does not count "
                  "twice (remove the copies to silence this)", SpecWarning, stacklevel=3)
    keep = np.ones(len(data.y), dtype=bool)
    keep[list(repeats)] = False
    return data.subset(keep)


def _noise_sd(frame, ds: Dataset, path, field: str) -> np.ndarray | None:
    """Known per-point noise sd (n,) from ``noise: sd`` or ``noise: sd_column``."""
    if ds.noise.sd is not None:
        return np.full(len(frame), float(ds.noise.sd))
    if ds.noise.sd_column is None:
        return None
    col = ds.noise.sd_column
    if col not in frame.columns:
        raise SpecError(f"noise sd column '{col}' is not in the CSV (it has "
                        f"{list(frame.columns)}); fix 'noise.sd_column'", file=str(path),
                        field=f"{field}.noise.sd_column")
    sd = _numeric_column(frame, col, path, field)
    if np.any(sd <= 0):
        rows = (np.flatnonzero(sd <= 0) + 2).tolist()
        raise SpecError(f"noise sd column '{col}' has {len(rows)} value(s) <= 0 on line(s) "
                        f"{rows[:10]}; a standard deviation must be positive",
                        file=str(path), field=f"{field}.noise.sd_column")
    return sd


def _numeric_column(frame, column: str, path, field: str) -> np.ndarray:
    if column not in frame.columns:
        raise SpecError(f"column '{column}' is not in the CSV (it has {list(frame.columns)}); "
                        "fix the 'columns' mapping", file=str(path), field=f"{field}.columns")
    values = frame[column]
    numeric = __import__("pandas").to_numeric(values, errors="coerce")
    bad = numeric.isna() & values.notna()
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0]) + 2
        raise SpecError(f"column '{column}' is not numeric ('{values[bad].iloc[0]}' on line "
                        f"{row}); fix the value", file=str(path), field=f"{field}.columns")
    arr = numeric.to_numpy(dtype=float)
    if not np.all(np.isfinite(arr)):
        rows = (np.flatnonzero(~np.isfinite(arr)) + 2).tolist()
        raise SpecError(f"column '{column}' has {len(rows)} missing/NaN/infinite value(s) "
                        f"on line(s) {rows[:10]}; fill or remove those rows",
                        file=str(path), field=f"{field}.columns")
    return arr


def _split_mask(frame, ds: Dataset, path, field: str) -> np.ndarray:
    if ds.split is None:
        return np.zeros(len(frame), dtype=bool)
    col = ds.split.column
    if col not in frame.columns:
        raise SpecError(f"split column '{col}' is not in the CSV (it has "
                        f"{list(frame.columns)}); fix 'split'", file=str(path),
                        field=f"{field}.split")
    values = frame[col].astype(str).str.strip()
    allowed = {ds.split.train, ds.split.test}
    unknown = sorted(set(values) - allowed)
    if unknown:
        raise SpecError(f"split column '{col}' has values {unknown}; only "
                        f"'{ds.split.train}' and '{ds.split.test}' are allowed",
                        file=str(path), field=f"{field}.split")
    mask = (values == ds.split.test).to_numpy()
    if mask.all():
        raise SpecError("every row is in the test split; keep some rows for calibration",
                        file=str(path), field=f"{field}.split")
    return mask


def outside_bounds(network: Network, keys, x) -> np.ndarray:
    """Which values of ``x`` (n, k), columns the variables ``keys`` (``model.name``), lie
    outside their variable's bounds: (n, k)."""
    x = np.asarray(x, dtype=float)
    out = np.zeros(x.shape, dtype=bool)
    for j, key in enumerate(keys):
        model, name = key.split(".")
        var = network.model(model).variable(name)
        out[:, j] = (x[:, j] < var.lower) | (x[:, j] > var.upper)
    return out


def _digits(value: float, var) -> str:
    """``value`` with the digits that tell it from the bound it lies beyond (``10`` for
    10.000000000000002 beside a bound of 10 would read as inside it)."""
    for bound in (var.lower, var.upper):
        if f"{value:g}" == f"{bound:g}" and value != bound:
            return repr(float(value))
    return f"{value:g}"


def _check_bounds(network: Network, ds: Dataset, keys: list[str], x: np.ndarray, path,
                  field: str) -> None:
    variables = [network.model(k.split(".")[0]).variable(k.split(".")[1]) for k in keys]
    for j, (key, var) in enumerate(zip(keys, variables, strict=True)):
        if getattr(var, "scale", "linear") == "log" and np.any(x[:, j] <= 0):
            rows = (np.flatnonzero(x[:, j] <= 0) + 2).tolist()
            raise SpecError(f"{key} has {len(rows)} value(s) <= 0 on line(s) {rows[:10]}, "
                            "but its scale is log (the surrogates take its logarithm); fix "
                            "or remove those rows", file=str(path), field=f"{field}.columns")
    mask = outside_bounds(network, keys, x)
    detail = [f"{key} in [{_digits(x[mask[:, j], j].min(), var)}, "
              f"{_digits(x[mask[:, j], j].max(), var)}] vs bounds "
              f"[{var.lower:g}, {var.upper:g}]"
              for j, (key, var) in enumerate(zip(keys, variables, strict=True))
              if mask[:, j].any()]
    outside = mask.any(axis=1)
    if not outside.any():
        return
    strict = ds.strict if ds.strict is not None else network.settings.strict
    msg = (f"{int(outside.sum())} of {len(x)} point(s) lie outside the model's input bounds "
           f"({'; '.join(detail)}); widen the bounds so the simulations cover the experiments")
    if strict:
        raise SpecError(msg, file=str(path), field=field)
    # the file as the spec names it, as the other warnings on its rows do
    warnings.warn(f"{ds.path}: {field}: {msg}", SpecWarning, stacklevel=3)


def read_all(network: Network) -> dict[str, ExperimentalData]:
    """Read every data set of ``network``, keyed by name.

    A measurement is counted once: two data sets reading the same file for the same
    output are a :class:`SpecError`, and a row (inputs, value and split) repeated within a
    data set, or in an earlier data set of the same output, is left out with a
    :class:`SpecWarning` that names it."""
    files: dict[tuple, str] = {}
    for ds in network.data:
        key = (network.path(ds.path).resolve(), ds.observes)
        if key in files:
            raise SpecError(f"data sets '{files[key]}' and '{ds.name}' both read '{ds.path}' "
                            f"for {ds.observes}, so each measurement would count twice; "
                            "remove one of them", file=network.source or None,
                            field=f"data.{ds.name}.path")
        files[key] = ds.name
    out, seen = {}, {}
    for ds in network.data:
        data = read_dataset(network, ds)
        held = seen.setdefault(ds.observes, {})
        repeats = {i: f"also in data set '{held[row]}'" for i, row in enumerate(_rows(data))
                   if row in held}
        if repeats and len(repeats) == len(data.y):
            others = sorted({held[row] for row in _rows(data)})
            raise SpecError(f"every row of data set '{ds.name}' repeats a measurement of "
                            f"{ds.observes} in data set {', '.join(map(repr, others))}, so "
                            "it adds nothing; remove it (or its copied rows)",
                            file=network.source or None, field=f"data.{ds.name}")
        out[ds.name] = _once(data, repeats, f"{ds.path}: data.{ds.name}")
        for row in _rows(out[ds.name]):
            held.setdefault(row, ds.name)
    return out
