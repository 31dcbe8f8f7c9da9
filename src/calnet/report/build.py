"""Render ``calnet run``'s results: figures, report.html, metrics.json and the posterior
CSVs, from :class:`calnet.results.RunResults` (nothing is computed here)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calnet.report import figures
from calnet.report.emulation import caption as emulation_caption
from calnet.report.emulation import emulation_section, slices_figure
from calnet.report.figures import unit_text, with_unit
from calnet.report.headline import BASELINES, headline, sampling_stages
from calnet.report.html import Section, Table, fmt, write_report
from calnet.report.metrics import write_metrics
from calnet.report.posterior_csv import write_posterior_csv
from calnet.report.reference import reference_rows
from calnet.report.verdict import comparison_verdicts
from calnet.results import CalibrationResult, RunResults, rhat_text


def _axis_labels(network, input_keys) -> list[str]:
    """Axis labels of a data set's process inputs: ``"x1"``, or ``"P (W)"`` with a unit."""
    return [with_unit(name, network.model(model).variable(name).unit)
            for model, name in (key.split(".", 1) for key in input_keys)]


def _sensitivity_figures(ctx, results: RunResults) -> None:
    """Sobol bars, predictive and process maps of the sensitivity results."""
    for name, e in results.sensitivity.items():
        d = ctx.data[name]
        res = e.indices
        ctx.figures[f"sobol {name}"] = figures.sobol_bars(
            list(res.names), res.S1, res.S1_conf, res.ST, res.ST_conf,
            ctx.out / "figures" / f"sobol_{name}.png", f"Sobol indices: {d.observes}")
        if e.map is None:
            continue
        grid = e.map
        out = ctx.network.model(d.observes.split(".")[0]).output(d.observes.split(".")[1])
        points = np.column_stack([d.x[:, 0], d.x[:, 1]])
        labels = dict(zip(("p_label", "v_label"), _axis_labels(ctx.network, d.input_keys),
                          strict=True))
        ctx.figures[f"map {name}"] = figures.predictive_map(
            grid.axis0, grid.axis1, grid.mean, ctx.out / "figures" / f"map_{name}.png",
            d.observes, out.unit, points=points, log_axes=grid.log, **labels)
        if grid.probability is not None:
            lower, upper = grid.criterion
            ctx.figures[f"process {name}"] = figures.process_map(
                grid.axis0, grid.axis1, grid.probability,
                ctx.out / "figures" / f"process_{name}.png",
                f"P({lower} <= {d.observes} <= {upper})", points=points, log_axes=grid.log,
                **labels)


def _statuses(counts: dict[str, int]) -> str:
    """``{"ok": 225, "failed": 5}`` -> ``"225 ok, 5 failed"`` (most frequent first)."""
    return ", ".join(f"{n} {k}" for k, n in sorted(counts.items(), key=lambda kv: -kv[1]))


def posterior_figures(calibration: CalibrationResult, folder) -> dict:
    """Prior-vs-posterior figure of every calibrated model, ``folder/posterior_<model>.png``:
    ``{model: path}``."""
    return {model: figures.prior_posterior_grid(
                [p.to_dict() for p in panels], Path(folder) / f"posterior_{model}.png",
                title=f"{model}: prior vs posterior")
            for model, panels in calibration.panels.items()}


def write_outputs(ctx, results: RunResults) -> None:
    """Figures, report.html and metrics.json for a finished run (``ctx``: the network,
    its data, the output folder, the figures drawn so far, the timings)."""
    net, out = ctx.network, ctx.out
    _sensitivity_figures(ctx, results)
    fig = ctx.figures
    fig["network"] = figures.network_diagram(
        [{"name": m.name, "inputs": list(m.input_names), "outputs": list(m.output_names),
          "measurable": [o.name for o in m.outputs if o.measurable]} for m in
         (net.model(n) for n in net.order)],
        [(ln.source_model, ln.target_model, f"{ln.source_var}->{ln.target_var}")
         for ln in net.links], out / "figures" / "network.png")
    # one plane: the data sets that take the same two inputs as the first such data set
    keys = next((d.input_keys for d in ctx.data.values() if d.x.shape[1] == 2), None)
    two_d = {k: (d.x[:, 0], d.x[:, 1], d.is_test) for k, d in ctx.data.items()
             if d.input_keys == keys}
    if two_d:
        p_label, v_label = _axis_labels(net, keys)
        fig["data"] = figures.data_grid(None, None, two_d, out / "figures" / "data.png",
                                        p_label=p_label, v_label=v_label)
    fig.update({f"posterior {model}": path for model, path in
                posterior_figures(results.calibration, out / "figures").items()})
    for name, d in ctx.data.items():
        p = results.predictions[name]
        observed = net.model(d.observes.split(".")[0]).output(d.observes.split(".")[1])
        fig[f"predictive {name}"] = figures.predictive_vs_observed(
            d.y, p.mean, p.lower, p.upper, d.is_test, out / "figures" / f"predictive_{name}.png",
            d.observes, observed.unit, log=observed.transform == "log")
        v = results.validation.get(name)
        if v is not None:
            fig[f"pit {name}"] = figures.pit_histogram(
                v.loo.get("pit", []), v.pit.tolist(), out / "figures" / f"pit_{name}.png",
                f"Predictive check: {d.observes}")
    for key, s in results.predicted_outputs.items():
        fig[f"predicted {key}"] = slices_figure(
            s, out / "figures" / f"predicted_{key}.png", _output_unit(net, key),
            {k: net.model(k.split(".")[0]).variable(k.split(".")[1]).unit
             for k in s.input_keys})
    write_metrics(out / "metrics.json", results.to_metrics())
    write_posterior_csv(out / "posterior", results.calibration.theta,
                        results.calibration.models)
    sections = _sections(ctx, results)
    titles = [s.title for s in sections]
    units = _units(ctx)
    box = headline(results, units=units,
                   warnings_section=titles.index("Warnings") + 1 if "Warnings" in titles
                   else None, predicted_units=_predicted_units(ctx, results))
    write_report(out, title=f"calnet report: {net.name}", sections=sections,
                 subtitle=net.description or None, headline=box)


def _units(ctx) -> dict[str, str]:
    """``{data set: unit of its observed output}``."""
    net = ctx.network
    return {k: net.model(d.observes.split(".")[0]).output(d.observes.split(".")[1]).unit
            for k, d in ctx.data.items()}


def _output_unit(network, key: str) -> str:
    model, output = key.split(".")
    return network.model(model).output(output).unit


def surrogate_label(network, key: str, transform: str | None, mean: str = "constant") -> str:
    """``"melt_pool.W (um), GP on ln, linear mean"``: a surrogate's output with its unit,
    the scale its GP models where that is not the output's own (its errors are on the
    output's), and a mean function other than the constant one."""
    label = with_unit(key, _output_unit(network, key))
    return (label + (", GP on ln" if transform == "log" else "")
            + (f", {mean} mean" if mean != "constant" else ""))


def _predicted_units(ctx, results: RunResults) -> dict[str, str]:
    return {k: _output_unit(ctx.network, k) for k in results.predicted_outputs}


def _caption(ctx, results: RunResults, key: str) -> str:
    """What a figure shows, in a sentence (figures are keyed ``"kind name"``)."""
    kind, _, name = key.partition(" ")
    d = ctx.data.get(name)
    observes = d.observes if d is not None else name
    if kind == "predicted":
        return emulation_caption(name, results.predicted_outputs[name])
    if kind == "network":
        return ("The model network: one box per model with its inputs and outputs (measured "
                "outputs in red); an arrow carries an upstream quantity into a downstream "
                "input.")
    if kind == "data":
        return ("Experimental settings of the data sets: filled markers are the points the "
                "calibration used, hollow markers the held-out test points.")
    if kind == "cv":
        return (f"Surrogate of {name}: k-fold cross-validated GP predictions against the "
                "simulator's values, with 95 % intervals.")
    if kind == "posterior":
        return (f"{name}: posterior of each parameter (histogram and density estimate, "
                "reflected at the bounds) against its prior over the calibration range; the "
                "red line is the posterior mode.")
    if kind == "predictive":
        return (f"{name}: posterior predictive mean of {observes} with 95 % intervals against "
                "the measurements; filled markers are training points, hollow markers "
                "held-out test points.")
    if kind == "pit":
        v = results.validation.get(name)
        which = ("left out (leave-one-out) and in-sample" if v is not None and "pit" in v.loo
                 else "in-sample (no leave-one-out)")
        return (f"{name}: where each measurement of {observes} falls in its predictive "
                f"distribution (PIT), {which}; a calibrated "
                "model gives a flat histogram, a U shape means intervals too narrow, a hump "
                "too wide, a slope a bias"
                + (f" (with {len(v.pit)} points a histogram shows little: read the "
                   "coverage and the tests in the table)" if v is not None and len(v.pit) < 10
                   else "") + ".")
    if kind == "sobol":
        return (f"{name}: Sobol indices of the predicted {observes} over the data's range of "
                "process inputs: first-order (S1) and total effect (ST), with 95 % bootstrap "
                "intervals.")
    if kind == "map":
        return (f"{name}: predicted {observes} (posterior predictive mean) over the process "
                "inputs, with the experimental settings as white markers.")
    if kind == "process":
        crit = ctx.network.settings.criteria.get(name)
        spec = (f"{crit.lower} <= {observes} <= {crit.upper}" if crit else observes)
        return (f"{name}: probability that {spec} over the process inputs; the black line "
                "is the 50 % contour.")
    return key


def _rhat(value, limit: float) -> str:
    """An R-hat cell: three decimals, four where three would hide that it exceeds
    ``limit``; a dash where there is none."""
    return fmt(None) if value is None else rhat_text(value, limit)


def _terms_table(cal) -> list[Table]:
    """Each data set's noise sd and discrepancy (sd, length scales) as calibrated."""
    rows = []
    for ds, d in cal.datasets.items():
        unit = unit_text(d["unit"])
        noise = d["noise_sd"]
        if "known" in noise:  # in the output's own unit, as the spec gives it
            rows.append([ds, "noise sd (known)", fmt(noise["known"]), "",
                         unit_text(noise["unit"])])
        else:
            rows.append([ds, "noise sd", fmt(noise["mean"]),
                         f"[{fmt(noise['q2.5'])}, {fmt(noise['q97.5'])}]", unit])
        if d["discrepancy_sd"] is None:
            rows.append([ds, "discrepancy", "none", "", ""])
            continue
        q = d["discrepancy_sd"]
        rows.append([ds, "discrepancy sd", fmt(q["mean"]),
                     f"[{fmt(q['q2.5'])}, {fmt(q['q97.5'])}]", unit])
        for name, q in d["length_scales"].items():
            rows.append([ds, f"discrepancy length scale, {name}", fmt(q["mean"]),
                         f"[{fmt(q['q2.5'])}, {fmt(q['q97.5'])}]", "(unit box)"])
    if not rows:
        return []
    return [Table("Noise and discrepancy per data set (sds on the output's modelled scale, "
                  "ln for a log output, as the unit column says; a known noise sd is in "
                  "the spec's unit, and on a log output it enters as sd / y at each "
                  "point; length scales on the unit box)",
                  ["data set", "quantity", "mean", "95% interval", "unit"], rows)]


def _sections(ctx, results: RunResults) -> list[Section]:
    fig, net, cal = ctx.figures, ctx.network, results.calibration
    summary = cal.models
    pick = lambda prefix: [(p, _caption(ctx, results, k))  # noqa: E731
                           for k, p in fig.items() if k.startswith(prefix)]
    how = ((f"Calibration: {cal.mode}" + (f", upstream plugged in by {cal.plug}"
                                          if cal.mode == "segmented" else ""))
           if cal.calibrated else "No data sets: emulation only, nothing calibrated")
    data_table = [Table("Data sets (measured points)",
                        ["data set", "observes", "points", "training points", "test points"],
                        [[k, d.observes, len(d.y), int((~d.is_test).sum()),
                          int(d.is_test.sum())] for k, d in ctx.data.items()])] if ctx.data else []
    overview = Section("Network and data", paragraphs=[
        f"Models in topological order: {' -> '.join(net.order)}. {how}"
        f". Wall time {_before_report(ctx.run_info['timings_s']):.1f} s for the stages "
        "before this report (run_info.json: each stage's time, and the total)." +
        (" Quick run: fewer draws, restarts and folds." if ctx.quick else "")],
        tables=[*data_table,
                Table("Simulation campaigns (simulator runs per model)",
                      ["model", "finished runs", "ok runs", "runs not ok (left out)",
                       "outcomes of the finished runs"],
                      [[k, c.n_total, c.n_ok, c.n_excluded, _statuses(c.status_counts)]
                       for k, c in results.campaigns.items()])],
        figures=pick("network") + pick("data"))
    sur = Section("Surrogates (k-fold cross-validation)", paragraphs=[
        "Each GP has a Matern 3/2 kernel and a mean function: the constant one unless the "
        "label names a linear or quadratic trend in the inputs, whose coefficients' "
        "uncertainty is part of its variance. With the model's surrogate: {mean: auto} "
        "(the default) it is the one of highest leave-one-out predictive density of the "
        "runs, among those with at least 5 runs per coefficient (docs/method.md, "
        "section 2)."], tables=[Table(
        "GP surrogates (simulator runs per output; CV MAPE only where the runs' outputs "
        "keep one sign and stay within a factor 100 of each other, or the GP is on ln)",
        ["output (unit)", "training runs", "runs left out (not ok or non-finite)",
         "CV folds k", "CV MAPE %", "CV RMSE (output's unit)", "CV 95% coverage"],
        [[surrogate_label(net, k, s.gp.transform, s.gp.mean), s.n_runs, s.n_excluded,
          *_cv_cells(s.cv)] for k, s in results.surrogates.items.items()])],
        figures=pick("cv "))
    rows = []
    for model, s in summary.items():
        if s.get("prior_only"):
            rows.append([model, "(no data: prior)"] + [""] * 7)
            continue
        if not s["parameters"]:
            rows.append([model, "(no parameters: its data's discrepancy and noise sampled)"]
                        + [""] * 5 + [fmt(s.get("max_rhat")), fmt(s.get("min_ess_bulk"))])
            continue
        for p, r in s["parameters"].items():
            rows.append([model, p, f"[{fmt(r['lower'])}, {fmt(r['upper'])}]", fmt(r["mode"]),
                         fmt(r["mean"]), f"[{fmt(r['q2.5'])}, {fmt(r['q97.5'])}]",
                         unit_text(r["unit"]), _rhat(r.get("rhat"), cal.rhat_max),
                         fmt(r.get("ess_bulk"))])
    # one row per calibration stage: its diagnostics are the stage's
    diag = [[st, ", ".join(s.get("datasets", ())), s.get("divergences", ""),
             _rhat(s.get("max_rhat"), cal.rhat_max), fmt(s.get("min_ess_bulk"))]
            for st, s in sampling_stages(summary).items()]
    terms = _terms_table(cal)
    units = _units(ctx)
    ref = reference_rows(results, units)  # only with a reference.json
    cal = Section("Calibration", paragraphs=[
        "The table gives each parameter's posterior mode (KDE"
        + (", as the reference study reports" if ref else "")
        + ") and mean (the summary box gives means); intervals are central 95 %.",
        *(f"{ds}: {d['priors']}." for ds, d in cal.datasets.items() if d.get("priors")),
        *cal.info], tables=[
        Table("Posterior summary", ["model", "parameter", "range", "mode", "mean", "95% interval",
                                    "unit", "R-hat", "bulk ESS"], rows),
        *terms,
        Table("Sampler diagnostics per calibration stage (all its sampled variables)",
              ["stage", "data sets", "divergences", "max R-hat", "min bulk ESS"], diag)],
        figures=pick("posterior "))
    vrows, lrows, loo_notes = [], [], []

    def row(name, predictor, r):
        return [name, predictor, fmt(r.get("rmse")), fmt(r.get("nrmse")), fmt(r.get("mape")),
                fmt(r.get("crps")), fmt(r.get("coverage95"))]

    for name, v in results.validation.items():
        for split, r in (("train", v.train), ("test", v.test)):
            if r is not None:
                vrows.append(row(name, f"calnet ({split})", r))
        for base, r in (v.baselines_test or {}).items():
            vrows.append(row(name, f"{BASELINES.get(base, base)} (test)", r))
        loo = v.loo
        if "calnet" in loo:
            vrows.append(row(name, "calnet (leave-one-out)", loo["calnet"]))
            vrows.append(row(name, "training mean (leave-one-out)", loo["training_mean"]))
        if "skipped" in loo:
            loo_notes.append(f"{name}: no leave-one-out ({loo['skipped']}).")
        if loo.get("influential"):
            loo_notes.append(influential_note(name, loo, unit_text(units.get(name))))
        if "elpd_loo" in loo:
            k = np.asarray(loo["pareto_k"])
            check, fit = loo["pit_check"], loo.get("fit_check", {})
            c = loo["calnet"]
            lrows.append([
                name, len(k), f"{fmt(loo['elpd_loo'])} ± {fmt(loo['elpd_se'])}",
                fmt(loo["p_loo"]), fmt(float(k.max())),
                f"{int(np.sum(k > loo['k_threshold']))} / {len(loo['refit'])} / "
                f"{loo['n_unreliable']}",
                " / ".join(fmt(c.get(f"pit_coverage{q}")) for q in (50, 80, 95)),
                ("flagged" if check["flagged"] or fit.get("flagged") else "ok")
                + f" (outside the band p = {_p(check['outside_pvalue'])}, uniformity "
                f"p = {_p(check['ks_pvalue'], 'too few points')}"
                + (f"; in-sample {fit['outside95']} of {fit['n']} outside, "
                   f"p = {_p(fit['outside_pvalue'])}" if fit.get("flagged") else "") + ")"])
    brows = [[name, src, fmt(share)] for name, v in results.validation.items()
             for src, share in v.variance_shares.items()]
    tables = [
        Table("Predictive accuracy (NRMSE = RMSE / range of the data set's measurements, "
              "every split on the same range; MAPE only "
              "where the measurements stay away from zero or are modelled on the log scale; "
              "RMSE and CRPS in the output's unit)",
              ["data set", "predictor", "RMSE", "NRMSE", "MAPE %", "CRPS", "95% coverage"],
              vrows)]
    if lrows:
        tables.append(Table(
            "Leave-one-out by Pareto-smoothed importance sampling: ELPD on the modelled "
            "scale; points with Pareto k > 0.7 are re-calibrated without the point",
            ["data set", "points", "ELPD ± se", "p_loo", "max k", "k > 0.7 / refitted / "
             "unreliable", "LOO coverage 50 / 80 / 95 %", "calibration (PIT)"], lrows))
    comparison, variant_notes = comparison_tables(results.comparison or {})
    variant_notes = comparison_verdicts(results.comparison or {}) + variant_notes
    tables += comparison
    tables.append(Table(
        "Uncertainty budget (share of the predictive variance at the data set's own "
        "settings, averaged over points; the discrepancy's share is what the model itself "
        "does not explain, counted after conditioning on the measurements: at measured "
        "settings they pin the discrepancy down, and with an orthogonal discrepancy it "
        "also leaves out what the parameters can absorb, so its share there can be far "
        "smaller than its sd in the calibration table suggests; away from the data it "
        "grows back toward that sd)",
        ["data set", "source", "share"], brows))
    val = Section("Prediction and validation", paragraphs=loo_notes + variant_notes,
                  tables=tables,
                  figures=pick("predictive ") + pick("pit "))
    srows, few = [], {}
    for name, e in results.sensitivity.items():
        if results.quick:
            few[name] = e.over_draws.n_draws
        ind, sp = e.indices, e.over_draws
        for j, nm in enumerate(ind.names):
            srows.append([name, nm, f"{fmt(ind.S1[j])} ± {fmt(ind.S1_conf[j])}",
                          f"{fmt(ind.ST[j])} ± {fmt(ind.ST_conf[j])}",
                          f"[{fmt(sp.ST_lo[j])}, {fmt(sp.ST_hi[j])}]"])
    sens = Section("Sensitivity (Sobol indices of the calibrated chain)",
                   paragraphs=[quick_spread_note(few)] if few else [], tables=[Table(
        "First-order and total-effect indices over the data's process box, uniform in "
        "each input's own scale (ln x for scale: log), of the posterior predictive mean "
        "(± the bootstrap 95 % half-width: the Monte Carlo error of the sample, not the "
        "surrogates' error; an input the data never vary spans its declared bounds); the "
        "last column is the central 95 % of ST computed for each posterior draw on "
        "one shared sample of half the size, so it shows the spread over the posterior "
        "and not that Monte Carlo error (the sample's error moves every draw's ST alike)",
        ["data set", "input", "S1", "ST", "ST over posterior draws (95 %)"], srows)],
        figures=pick("sobol ") + pick("map ") + pick("process "))
    sections = [overview, sur] + ([cal] if rows else []) + ([val, sens] if ctx.data else [])
    if results.predicted_outputs:
        sections.append(emulation_section(results.predicted_outputs,
                                          _predicted_units(ctx, results), pick("predicted ")))
    if ref:
        note = results.reference.get("note")
        sections.append(Section("Comparison with the reference study",
                                paragraphs=[note] if note else [],
            tables=[Table("Reference vs calnet", ["quantity", "reference study", "calnet"], ref)]))
    if results.warnings:
        sections.append(Section("Warnings", paragraphs=list(results.warnings)))
    return sections


def _before_report(timings: dict[str, float]) -> float:
    """Seconds of the stages finished before the report, from the stage timings that
    run_info.json holds: the report's wall time is their sum, not a second clock (summed
    exactly, so that the order the stages are listed in does not move its last digit)."""
    return math.fsum(v for k, v in timings.items() if k not in ("total", "report"))


def quick_spread_note(draws: dict[str, int]) -> str:
    """What a quick run's spread of the total indices over posterior draws is worth:
    ``draws`` gives the number of draws per data set."""
    counts = sorted(set(draws.values()))
    n = (f"{counts[0]} posterior draws" if len(counts) == 1
         else ", ".join(f"{k}: {v}" for k, v in draws.items()) + " posterior draws")
    return (f"Quick run: the spread of ST over posterior draws comes from {n} only, so it "
            "is indicative, not a 95 % interval; run without --quick for a meaningful "
            "spread.")


def _p(value, missing: str = "") -> str:
    """A p-value cell: an en dash (and why) where there is none."""
    if value is None or not np.isfinite(value):
        return "\u2013" + (f" ({missing})" if missing else "")
    return fmt(value)


def influential_note(name: str, loo: dict, unit: str = "", most: int = 5) -> str:
    """The points of a data set whose Pareto k exceeds the threshold, named by their
    process inputs and measurement, highest k first: the measurements the calibration
    leans on most, or outliers."""
    points = loo["influential"]

    def how(p):
        return ((", re-calibrated without it" if p["refit"] else "")
                + (", its density from the Gaussian of its predictive"
                   if p.get("density", "").startswith("moment") else ""))
    said = [f"{', '.join(f'{k} = {fmt(v)}' for k, v in p['inputs'].items())}: "
            f"{fmt(p['y'])}{' ' + unit if unit else ''} (k = {fmt(p['pareto_k'])}{how(p)})"
            for p in points[:most]]
    more = f" and {len(points) - most} more" if len(points) > most else ""
    return (f"{name}: {len(points)} point{'s' if len(points) > 1 else ''} with Pareto k > "
            f"{fmt(loo['k_threshold'])}, which the posterior leans on most (a measurement "
            f"to check, or one the model cannot explain): {'; '.join(said)}{more}.")


def comparison_tables(comparison) -> tuple[list[Table], list[str]]:
    """The comparison of discrepancy variants (``{data set: {model: VariantScore}}``): a
    table per data set, and one paragraph with the variants' notes (convergence and
    surrogate checks), each said once: a variant's notes are its calibration's, the same
    for every data set."""
    tables = [Table(
        f"{name}: the spec's discrepancy against variants, by leave-one-out (ELPD "
        "difference to the best model and its standard error, as ArviZ's compare gives "
        "them; the sentences compare each variant with the spec's model instead; stacking "
        "weight; max k of the points not refitted exactly; the variants are calibrated "
        "beside the spec with fewer draws)",
        ["model", "ELPD", "difference", "se of difference", "weight", "max k", "draws"],
        [[variant, fmt(r.elpd_loo), fmt(r.elpd_diff), fmt(r.dse),
          fmt(r.weight if r.weight >= 1e-4 else 0.0), fmt(r.max_pareto_k), str(r.draws)]
         for variant, r in cmp.items()])
        for name, cmp in comparison.items()]
    notes = list(dict.fromkeys(f"{variant}: {n}" for cmp in comparison.values()
                               for variant, r in cmp.items() for n in r.notes))
    return tables, (["Notes on the variants compared below: " + "; ".join(notes) + "."]
                    if notes else [])


def _cv_cells(cv) -> list:
    """k, MAPE, RMSE and 95 % coverage of a surrogate's cross-validation (dashes without)."""
    m = cv.metrics() if cv is not None else {}
    return [m.get("k"), fmt(m.get("mape")), fmt(m.get("rmse")), fmt(m.get("coverage95"))]
