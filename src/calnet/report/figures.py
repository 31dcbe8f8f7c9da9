"""Report figures: plain arrays in, a PNG file out.

Every function takes NumPy arrays (or lists, dicts) and a destination ``path``, writes a PNG
at about 110 dpi and returns the path as a :class:`pathlib.Path`. Matplotlib is imported
lazily and only its object-oriented API is used (``Figure`` with the Agg canvas, never
``pyplot``), so nothing here touches global plotting state or needs a display.

Axes default to the process inputs of the reference case: laser power ``P`` in W and scan
speed ``v`` in m/s; pass ``p_label`` / ``v_label`` to change them.

Examples
--------
>>> import tempfile, pathlib
>>> out = sobol_bars(["P", "v"], [0.2, 0.7], [0.05, 0.05], [0.25, 0.75], [0.05, 0.05],
...                  pathlib.Path(tempfile.mkdtemp()) / "sobol.png", "width")
>>> out.stat().st_size > 0
True
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from calnet.report.network_diagram import network_diagram

__all__ = ["data_grid", "prior_posterior", "prior_posterior_grid", "predictive_vs_observed",
           "predictive_map", "process_map", "reflected_kde", "sobol_bars", "network_diagram"]

DPI = 110
P_LABEL = "laser power P (W)"
V_LABEL = "scan speed v (m/s)"
TRAIN_COLOR, TEST_COLOR = "#1f77b4", "#d62728"
DATASET_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">")


def unit_text(unit: str | None) -> str:
    """A unit as a table shows it: empty for no unit and for the dimensionless ``"1"``."""
    return "" if unit in (None, "", "1") else str(unit)


def with_unit(label: str, unit: str | None) -> str:
    """``"P (W)"``; the bare label for no unit or the dimensionless ``"1"`` (no ``"(1)"``)."""
    return f"{label} ({unit_text(unit)})" if unit_text(unit) else str(label)


def _figure(width: float, height: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained")


def _save(fig: Any, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, format="png")
    return path


def data_grid(P: Any, v: Any, labels_by_dataset: Mapping[str, Sequence[Any]],
              path: str | Path, *, p_label: str = P_LABEL, v_label: str = V_LABEL,
              title: str = "Experimental settings") -> Path:
    """Experimental settings of each data set in the (P, v) plane.

    Parameters
    ----------
    P, v : array, shape (n,), or None
        Background settings drawn as small grey dots (e.g. the simulation campaign
        design), W and m/s; ``None`` for none.
    labels_by_dataset : dict
        ``{dataset name: (P, v)}`` or ``{name: (P, v, is_test)}`` with arrays of shape
        (m,) and an optional boolean test mask; one marker per data set, test points
        drawn hollow.
    path : str or Path
        Destination PNG.

    Returns
    -------
    Path
    """
    fig = _figure(7.2, 4.5)
    ax = fig.add_subplot()
    if P is not None and v is not None:
        ax.scatter(np.asarray(P), np.asarray(v), s=6, c="0.75", label="simulation design",
                   zorder=1)
    for k, (name, entry) in enumerate(labels_by_dataset.items()):
        p_ds, v_ds = np.asarray(entry[0], float), np.asarray(entry[1], float)
        test = (np.asarray(entry[2], bool) if len(entry) > 2 and entry[2] is not None
                else np.zeros(p_ds.shape, bool))
        color, marker = f"C{k % 10}", DATASET_MARKERS[k % len(DATASET_MARKERS)]
        ax.scatter(p_ds[~test], v_ds[~test], marker=marker, s=40, color=color,
                   edgecolors="k", linewidths=0.5, label=f"{name} (train)", zorder=3)
        if test.any():
            ax.scatter(p_ds[test], v_ds[test], marker=marker, s=60, facecolors="none",
                       edgecolors=color, linewidths=1.6, label=f"{name} (test)", zorder=4)
    ax.set(xlabel=p_label, ylabel=v_label, title=title)
    ax.grid(alpha=0.3)
    # beside the axes, never on the points
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    return _save(fig, path)


def reflected_kde(samples: Any, lower: float, upper: float, x: Any) -> np.ndarray:
    """Gaussian KDE of draws confined to ``[lower, upper]``, corrected at the bounds by
    reflection.

    A plain KDE spreads the mass of draws near a bound beyond it and so drops to about
    half the true density at the bound. Adding the kernels of the draws mirrored at each
    bound (Schuster 1985) puts that mass back: ``f(x) = k(x) + k(2 lower - x) +
    k(2 upper - x)`` with ``k`` the Gaussian KDE of the draws (Scott's bandwidth). Zero
    outside the bounds; infinite bounds are not reflected.

    Parameters
    ----------
    samples : array, shape (n,)
        Draws inside ``[lower, upper]``.
    lower, upper : float
        The bounds (parameter units).
    x : array, shape (k,)
        Where to evaluate the density.

    Returns
    -------
    ndarray, shape (k,)
        Density per parameter unit; integrates to 1 over ``[lower, upper]`` up to the
        mass farther than one bound width beyond a bound.

    Examples
    --------
    >>> draws = np.random.default_rng(0).uniform(0.0, 1.0, 5000)
    >>> bool(abs(reflected_kde(draws, 0.0, 1.0, [0.0])[0] - 1.0) < 0.15)
    True
    """
    from scipy.stats import gaussian_kde

    x = np.asarray(x, float)
    kde = gaussian_kde(np.asarray(samples, float).ravel())
    density = kde(x)
    for bound in (lower, upper):
        if np.isfinite(bound):
            density = density + kde(2.0 * bound - x)
    return np.where((x >= lower) & (x <= upper), density, 0.0)


def _draw_prior_posterior(ax: Any, p: Mapping[str, Any], *, legend: bool = True) -> None:
    """One prior-vs-posterior panel from a dict with the keys of :func:`prior_posterior`."""
    lower, upper = float(p["lower"]), float(p["upper"])
    samples = np.asarray(p["posterior_samples"], float).ravel()
    samples = samples[np.isfinite(samples)]
    inside = samples[(samples >= lower) & (samples <= upper)]
    bins = np.linspace(lower, upper, 31)
    if inside.size > 1 and 0 < np.ptp(inside) < 0.5 * (upper - lower):
        # a narrow posterior: bins over its own range, so that it is not two bars
        bins = np.linspace(inside.min(), inside.max(), 21)
    ax.hist(inside, bins=bins, density=True, color="#9ecae1", edgecolor="white",
            label="posterior")
    if inside.size > 1 and np.ptp(inside) > 0:
        xs = np.union1d(np.linspace(lower, upper, 200),
                        np.linspace(inside.min(), inside.max(), 200))
        ax.plot(xs, reflected_kde(inside, lower, upper, xs), color="#08519c", lw=1.5,
                label="posterior KDE")
    ax.plot(np.asarray(p["prior_pdf_x"], float), np.asarray(p["prior_pdf_y"], float),
            color="0.3", ls="--", lw=1.2, label="prior")
    notes = []
    mode, ref = p.get("mode"), p.get("reference")
    if mode is not None and np.isfinite(mode):
        ax.axvline(float(mode), color="#d62728", lw=1.5, label="posterior mode")
        notes.append(f"mode {mode:.4g}")
    if ref is not None and np.isfinite(ref):
        if lower <= ref <= upper:
            ax.axvline(float(ref), color="k", ls=":", lw=1.5, label="reference study")
            notes.append(f"ref. {ref:.4g}")
        else:
            notes.append(f"ref. {ref:.4g} (outside range)")
    unit = p.get("unit") or ""
    ax.set_xlim(lower, upper)
    ax.set_xlabel(with_unit(p["name"], unit))
    ax.set_ylabel("density")
    ax.set_title(", ".join(notes), fontsize=8)
    if legend:
        ax.legend(fontsize=7, loc="best")


def prior_posterior(name: str, unit: str, lower: float, upper: float, prior_pdf_x: Any,
                    prior_pdf_y: Any, posterior_samples: Any, path: str | Path,
                    mode: float | None = None, reference: float | None = None) -> Path:
    """Posterior histogram and KDE of one parameter against its prior density.

    Parameters
    ----------
    name, unit : str
        Parameter name and unit (unit ``"1"`` or empty for dimensionless).
    lower, upper : float
        Prior range, the x-axis limits (parameter units).
    prior_pdf_x, prior_pdf_y : array, shape (k,)
        Prior density evaluated on a grid (per parameter unit).
    posterior_samples : array, shape (n_samples,)
        Posterior draws (all chains pooled).
    path : str or Path
        Destination PNG.
    mode : float, optional
        Posterior mode, drawn as a solid vertical line.
    reference : float, optional
        Reference-study value, a dotted line (or a note if outside the prior range).

    Returns
    -------
    Path
    """
    fig = _figure(4.5, 3.4)
    _draw_prior_posterior(fig.add_subplot(), dict(
        name=name, unit=unit, lower=lower, upper=upper, prior_pdf_x=prior_pdf_x,
        prior_pdf_y=prior_pdf_y, posterior_samples=posterior_samples, mode=mode,
        reference=reference))
    return _save(fig, path)


def prior_posterior_grid(params: Sequence[Mapping[str, Any]], path: str | Path, *,
                         ncols: int = 3, title: str | None = None) -> Path:
    """A grid of :func:`prior_posterior` panels, one per parameter.

    Parameters
    ----------
    params : list of dict
        Each with the keys ``name, unit, lower, upper, prior_pdf_x, prior_pdf_y,
        posterior_samples`` and optionally ``mode, reference``.
    path : str or Path
        Destination PNG.
    ncols : int
        Panels per row.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
    """
    n = max(len(params), 1)
    ncols = min(ncols, n)
    nrows = -(-n // ncols)
    fig = _figure(4.0 * ncols, 3.0 * nrows)
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    for ax, p in zip(axes, params, strict=False):
        _draw_prior_posterior(ax, p, legend=False)
    for ax in axes[len(params):]:
        ax.set_axis_off()
    handles: dict[str, Any] = {}
    for ax in axes[:len(params)]:  # one shared legend with every artist kind used
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    # at most as many legend columns as fit the figure's width (about 1.5 in each)
    fig.legend(list(handles.values()), list(handles), loc="outside lower center",
               ncols=max(1, min(len(handles), int(4.0 * ncols / 1.5))), fontsize=8)
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def predictive_vs_observed(y_obs: Any, mean: Any, lo: Any, hi: Any, is_test: Any,
                           path: str | Path, label: str, unit: str, *,
                           log: bool = False) -> Path:
    """Posterior predictive mean with 95 % intervals against the observations.

    Parameters
    ----------
    y_obs, mean, lo, hi : array, shape (n,)
        Observations, predictive means and 2.5 / 97.5 % bounds (output units).
    is_test : array of bool, shape (n,)
        Held-out points (hollow red markers); the rest are training points.
    path : str or Path
        Destination PNG.
    label, unit : str
        Output name and unit for the axes.
    log : bool
        The output is modelled on the log scale: both axes are logarithmic where its
        values (all positive) span more than a decade, where linear axes would crowd the
        small values into a corner.

    Returns
    -------
    Path
    """
    y_obs, mean = np.asarray(y_obs, float), np.asarray(mean, float)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    test = np.asarray(is_test, bool)
    fig = _figure(4.8, 4.5)
    ax = fig.add_subplot()
    allv = np.concatenate([y_obs, lo, hi])
    allv = allv[np.isfinite(allv)]
    span = (allv.min(), allv.max()) if allv.size else (0.0, 1.0)
    logs = bool(log and allv.size and span[0] > 0 and span[1] > 10 * span[0])
    if logs:
        ax.set(xscale="log", yscale="log")
        ends = [span[0] / 1.2, span[1] * 1.2]
    else:
        pad = 0.05 * (span[1] - span[0] or 1.0)
        ends = [span[0] - pad, span[1] + pad]
    ax.plot(ends, ends, color="0.5", lw=1, ls="--", label="1:1")
    for mask, name, color, face in ((~test, "train", TRAIN_COLOR, TRAIN_COLOR),
                                    (test, "test", TEST_COLOR, "white")):
        if mask.any():
            ax.errorbar(y_obs[mask], mean[mask],
                        yerr=[mean[mask] - lo[mask], hi[mask] - mean[mask]], fmt="o",
                        color=color, mfc=face, ms=6, capsize=3, lw=1, label=name)
    ax.set(xlabel=with_unit(f"observed {label}", unit),
           ylabel=with_unit(f"predicted {label}", unit),
           title=f"{label}: posterior predictive (95 %)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def _mesh(P_grid: Any, v_grid: Any, z: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    P_grid, v_grid, z = (np.asarray(a, float) for a in (P_grid, v_grid, z))
    if P_grid.ndim == 1 and v_grid.ndim == 1:
        P_grid, v_grid = np.meshgrid(P_grid, v_grid)
    if not P_grid.shape == v_grid.shape == z.shape:
        raise ValueError(f"grid shapes disagree: P {P_grid.shape}, v {v_grid.shape}, values "
                         f"{z.shape}; give 1-D axes (nP,), (nv,) with values (nv, nP), or "
                         "2-D meshgrids of the values' shape")
    return P_grid, v_grid, z


def _draw_points(ax: Any, points: Any) -> None:
    if points is None:
        return
    groups = points.items() if isinstance(points, Mapping) else [("experiments", points)]
    for k, (name, pts) in enumerate(groups):
        pts = np.asarray(pts, float).reshape(-1, 2)
        ax.scatter(pts[:, 0], pts[:, 1], s=25, marker=DATASET_MARKERS[k % 9], color="white",
                   edgecolors="k", linewidths=0.8, label=name, zorder=3)
    # under the figure, off the map
    ax.figure.legend(*ax.get_legend_handles_labels(), fontsize=8, loc="outside lower center",
                     ncols=4)


def predictive_map(P_grid: Any, v_grid: Any, mean_2d: Any, path: str | Path, label: str,
                   unit: str, points: Any = None, *, p_label: str = P_LABEL,
                   v_label: str = V_LABEL, log_axes: tuple[bool, bool] = (False, False)
                   ) -> Path:
    """Predictive mean of an output over the (P, v) plane.

    Parameters
    ----------
    P_grid, v_grid : array
        1-D axes of shapes (nP,), (nv,), or 2-D meshgrids of the shape of ``mean_2d``.
    mean_2d : array, shape (nv, nP)
        Predictive mean (output units).
    path : str or Path
        Destination PNG.
    label, unit : str
        Output name and unit for the colour bar.
    points : array (m, 2) of (P, v), or dict {name: (m, 2) array}, optional
        Experimental settings to overlay.
    log_axes : (bool, bool)
        Logarithmic x and y axes (inputs of ``scale: log``).

    Returns
    -------
    Path
    """
    P_grid, v_grid, z = _mesh(P_grid, v_grid, mean_2d)
    fig = _figure(6.0, 4.5)
    ax = fig.add_subplot()
    mesh = ax.pcolormesh(P_grid, v_grid, z, shading="auto", cmap="viridis")
    if np.ptp(z[np.isfinite(z)]) > 0:
        cs = ax.contour(P_grid, v_grid, z, levels=8, colors="white", linewidths=0.6)
        ax.clabel(cs, fontsize=7, fmt="%.3g")
    fig.colorbar(mesh, ax=ax, label=with_unit(label, unit))
    _draw_points(ax, points)
    ax.set(xlabel=p_label, ylabel=v_label, title=f"predicted {label}")
    _log_axes(ax, log_axes)
    return _save(fig, path)


def _log_axes(ax, log_axes: tuple[bool, bool]) -> None:
    if log_axes[0]:
        ax.set_xscale("log")
    if log_axes[1]:
        ax.set_yscale("log")


def process_map(P_grid: Any, v_grid: Any, prob_2d: Any, path: str | Path, label: str,
                points: Any = None, *, p_label: str = P_LABEL,
                v_label: str = V_LABEL, log_axes: tuple[bool, bool] = (False, False)
                ) -> Path:
    """Probability of meeting a specification over the (P, v) plane, with its 0.5 contour.

    Parameters
    ----------
    P_grid, v_grid : array
        As in :func:`predictive_map`.
    prob_2d : array, shape (nv, nP)
        Probabilities in [0, 1].
    path : str or Path
        Destination PNG.
    label : str
        The specification, e.g. ``"PDAS < 0.35 um"``.
    points : optional
        Experimental settings to overlay, as in :func:`predictive_map`.
    log_axes : (bool, bool)
        As in :func:`predictive_map`.

    Returns
    -------
    Path
    """
    P_grid, v_grid, z = _mesh(P_grid, v_grid, prob_2d)
    fig = _figure(6.0, 4.5)
    ax = fig.add_subplot()
    mesh = ax.pcolormesh(P_grid, v_grid, z, shading="auto", cmap="RdYlGn", vmin=0.0, vmax=1.0)
    finite = z[np.isfinite(z)]
    if finite.size and finite.min() < 0.5 < finite.max():
        cs = ax.contour(P_grid, v_grid, z, levels=[0.5], colors="k", linewidths=1.5)
        ax.clabel(cs, fontsize=8, fmt="p = 0.5")
    fig.colorbar(mesh, ax=ax, label="probability")
    _draw_points(ax, points)
    ax.set(xlabel=p_label, ylabel=v_label, title=f"P({label})")
    _log_axes(ax, log_axes)
    return _save(fig, path)


def sobol_bars(names: Sequence[str], S1: Any, S1_conf: Any, ST: Any, ST_conf: Any,
               path: str | Path, title: str) -> Path:
    """First-order and total-effect Sobol indices as grouped bars with confidence bars.

    Parameters
    ----------
    names : list of str, length d
        Input names.
    S1, S1_conf, ST, ST_conf : array, shape (d,)
        Indices and their confidence half-widths (dimensionless).
    path : str or Path
        Destination PNG.
    title : str
        Figure title (e.g. the output name).

    Returns
    -------
    Path
    """
    x = np.arange(len(names))
    fig = _figure(max(3.5, 1.2 * len(names) + 2.0), 3.6)
    ax = fig.add_subplot()
    w = 0.38
    ax.bar(x - w / 2, np.asarray(S1, float), w, yerr=np.asarray(S1_conf, float), capsize=4,
           color="#9ecae1", edgecolor="k", lw=0.5, label="first order S1")
    ax.bar(x + w / 2, np.asarray(ST, float), w, yerr=np.asarray(ST_conf, float), capsize=4,
           color="#08519c", edgecolor="k", lw=0.5, label="total effect ST")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xticks(x, list(names))
    top = np.nanmax(np.concatenate([np.asarray(S1, float) + np.asarray(S1_conf, float),
                                    np.asarray(ST, float) + np.asarray(ST_conf, float), [1]]))
    ax.set_ylim(min(0.0, ax.get_ylim()[0]), max(1.05, top * 1.05))
    ax.set(ylabel="Sobol index", title=title)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def pit_histogram(pit_loo: Any, pit_post: Any, path: str | Path, title: str,
                  bins: int = 10) -> Path:
    """Posterior predictive check: histograms of the leave-one-out and the in-sample PIT
    values, with the uniform density a calibrated predictive gives.

    Parameters
    ----------
    pit_loo, pit_post : array, shape (n,) and (m,)
        PIT values in [0, 1] (``pit_loo`` may be empty).
    path : str or Path
        Destination PNG.
    title : str

    Returns
    -------
    Path
    """
    fig = _figure(4.6, 3.2)
    ax = fig.add_subplot()
    edges = np.linspace(0.0, 1.0, bins + 1)
    post, loo = np.asarray(pit_post, float), np.asarray(pit_loo, float)
    if len(post):  # filled, and leave-one-out as an outline over it: no blended shade
        ax.hist(post, bins=edges, density=True, color="#9ecae1", edgecolor="k", lw=0.5,
                label=f"posterior predictive, all {len(post)} points")
    if len(loo):
        ax.hist(loo, bins=edges, density=True, histtype="step", color="#08519c", lw=2,
                label=f"leave-one-out, {len(loo)} calibration points")
    ax.axhline(1.0, color="k", ls="--", lw=1, label="calibrated (uniform)")
    ax.set(xlim=(0, 1), xlabel="PIT: predictive probability below the measurement",
           ylabel="density", title=title)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=2,
              frameon=False)
    return _save(fig, path)
