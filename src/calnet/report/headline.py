"""The box at the top of the report: estimates, prediction error and warnings, one screen.

Built from what the stages computed (:class:`calnet.results.RunResults`: the calibration
with its posterior summary and convergence limits, the validation of each data set, the
warnings); nothing is recomputed here.

Examples
--------
>>> from calnet.results import CalibrationResult, RunResults
>>> summary = {"M": {"parameters": {"k": {"unit": "W", "mean": 2.0, "q2.5": 1.5,
...                                       "q97.5": 2.5}},
...                  "max_rhat": 1.002, "min_ess_bulk": 900.0, "divergences": 0,
...                  "stage": "M"}}
>>> cal = CalibrationResult(mode="joint", plug="-", calibrated=True, models=summary,
...                         rhat_max=1.01, ess_min=400)
>>> box = headline(RunResults("net", False, {}, None, cal))
>>> box.tables[0].rows
(('M.k', 2.0, '[1.5, 2.5]', 'W'),)
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from calnet.report.emulation import headline_table
from calnet.report.figures import unit_text
from calnet.report.html import Headline, Table, fmt
from calnet.report.verdict import comparison_verdicts
from calnet.results import CalibrationResult, DatasetValidation, RunResults, rhat_text

#: bullets in the box; the rest are counted and left to the Warnings section
MAX_WARNINGS = 6
#: the sampler's convergence warnings (diagnostics.convergence_problems), shown here as
#: one line per stage instead
_CONVERGENCE = re.compile(r"R-hat [\d.]+ > |bulk ESS \d+ < |\d+ divergent transitions")
BASELINES = {"training_mean": "training mean", "power_law": "power law",
             "direct_gp": "direct GP"}


def headline(results: RunResults, *, units: Mapping[str, str] | None = None,
             warnings_section: int | None = None,
             predicted_units: Mapping[str, str] | None = None) -> Headline:
    """The report's headline box.

    Parameters
    ----------
    results : RunResults
        The run's results: the calibration (mode, posterior summary, notes, surrogate
        checks, convergence limits), the validation of each data set (test,
        leave-one-out and baseline errors), the predicted outputs and every warning.
    units : dict, optional
        ``{data set: unit of its observed output}``, for the RMSE column.
    warnings_section : int, optional
        Number of the report's Warnings section, named in the closing line.
    predicted_units : dict, optional
        ``{model.output: unit}`` of the outputs in ``results.predicted_outputs``.

    Returns
    -------
    Headline
    """
    cal = results.calibration
    tables = [_parameter_table(cal.models),
              _error_table(results.validation, units or {}),
              headline_table(results.predicted_outputs, predicted_units or {})]
    warnings = _warnings(results)
    shown = warnings[:MAX_WARNINGS]
    more = None
    if warnings_section is not None and results.warnings:
        hidden = len(warnings) - len(shown)
        more = ((f"{hidden} more not shown here. " if hidden else "")
                + f"The run's {len(results.warnings)} warning(s) in full: section "
                f"{warnings_section}.")
    return Headline(tables=[t for t in tables if t.rows],
                    lines=_lines(results), warnings=shown, more=more)


def _parameter_table(summary: Mapping[str, Any]) -> Table:
    """One row per calibrated parameter: posterior mean and central 95 % interval."""
    rows, seen = [], set()
    for model, s in summary.items():
        for name, r in s.get("parameters", {}).items():
            label = name if r.get("shared") else f"{model}.{name}"
            if label in seen:
                continue
            seen.add(label)
            if r.get("shared"):
                label += " (shared)"
            if r.get("plugged"):
                label += " (plugged in)"
            elif r.get("prior"):
                label += " (its prior: no data depends on it)"
            rows.append([label, r["mean"], f"[{fmt(r['q2.5'])}, {fmt(r['q97.5'])}]",
                         unit_text(r.get("unit"))])
    return Table("Calibrated parameters", ["parameter", "posterior mean", "95 % interval",
                                           "unit"], rows)


def _cell(m: Mapping[str, Any] | None) -> str:
    """``"12.9 (12.3 %)"``: RMSE and MAPE of one predictor (RMSE alone where the metrics
    hold no MAPE, e.g. for outputs near zero)."""
    if not m:
        return fmt(None)
    if "error" in m:
        return "failed"
    rmse = fmt(m.get("rmse"), 3)
    return rmse if m.get("mape") is None else f"{rmse} ({fmt(m['mape'], 3)} %)"


def _error_table(validation: Mapping[str, DatasetValidation],
                 units: Mapping[str, str]) -> Table:
    """Per data set, calnet's prediction error beside the baselines' on the same points:
    held-out test points where the data set has them, else leave-one-out."""
    used = [b for b in BASELINES if any(b in (v.baselines_test or {}) or b in v.loo
                                        for v in validation.values())]
    rows = []
    for name, v in validation.items():
        loo = v.loo
        if v.test is not None:
            where, calnet, base = (f"{v.test['n']} held-out points", v.test,
                                   v.baselines_test or {})
        elif "calnet" in loo:
            where, calnet = f"leave-one-out, {loo['calnet']['n']} points", loo["calnet"]
            base = {b: loo[b] for b in used if b in loo}
        else:
            where, calnet, base = f"{v.train['n']} training points (no test)", v.train, {}
        rows.append([name, where, unit_text(units.get(name)), _cell(calnet)]
                    + [_cell(base.get(b)) for b in used])
    mape = any(" %)" in cell for row in rows for cell in row[3:])
    return Table("Prediction error: RMSE (MAPE)" if mape else "Prediction error: RMSE",
                 ["data set", "evaluated on", "unit", "calnet"] + [BASELINES[b] for b in used],
                 rows)


def sampling_stages(summary: Mapping[str, Any]) -> dict[str, Mapping[str, Any]]:
    """One entry per sampling stage, with its own data sets and diagnostics (models
    sampled together share them; a model whose shared parameter another model's stage
    samples is in two)."""
    out: dict[str, Mapping[str, Any]] = {}
    for s in summary.values():
        if not s.get("prior_only") and "stage" in s:
            for name, st in s.get("stages", {s["stage"]: s}).items():
                out.setdefault(name, st)
    return out


def _lines(results: RunResults) -> list[str]:
    cal, summary = results.calibration, results.calibration.models
    if not cal.calibrated:
        return ["No data sets: emulation only, nothing calibrated; the surrogates predict "
                + (", ".join(results.predicted_outputs) or "nothing (settings."
                   "predict is empty)") + " through the chain." + (
                    " Quick run: fewer restarts and folds." if results.quick else "")]
    if not any(s.get("parameters") for s in summary.values()):
        lines = [f"Calibration: {cal.mode}; no calibration parameters, so only "
                 "the data sets' discrepancy and unknown noise are calibrated."]
    else:
        calibrated = [m for m, s in summary.items() if not s.get("prior_only")]
        prior = [m for m, s in summary.items() if s.get("prior_only")]
        where = {name: st.get("datasets", ()) for name, st in sampling_stages(summary).items()}
        lines = [f"Calibration: {cal.mode}, {len(calibrated)} model(s) calibrated"
                 + (" (" + "; ".join(st + (f" with {', '.join(ds)}" if ds else "")
                                     for st, ds in where.items()) + ")" if where else "")
                 + (f"; at their prior (no data): {', '.join(prior)}" if prior else "")
                 + "." + (" Quick run: fewer draws, restarts and folds." if results.quick
                          else "")]
    stages = sampling_stages(summary)
    if stages:
        rhat = max(s["max_rhat"] for s in stages.values())
        ess = min(s["min_ess_bulk"] for s in stages.values())
        div = sum(s["divergences"] for s in stages.values())
        ok = rhat <= cal.rhat_max and ess >= cal.ess_min and div == 0
        lines.append(f"Sampler: max R-hat {rhat_text(rhat, cal.rhat_max)} (limit "
                     f"{cal.rhat_max}), min bulk ESS "
                     f"{ess:.0f} (limit {cal.ess_min}), {div} divergent transitions: "
                     + ("within the limits." if ok else "see the warnings."))
    return lines + [f"Comparison: {v}" for v in comparison_verdicts(results.comparison or {})]


def _surrogate_warning(name: str, check: Mapping[str, Any]) -> str:
    worst = max(check["surrogate_sd"], key=check["surrogate_sd"].get)
    model = worst.split(".")[0]
    head = (f"{name}: the surrogate, not the data, sets the answer (surrogate sd "
            f"{check['ratio']:.2g} x the data's noise and discrepancy sd, mostly {worst})")
    if check.get("extrapolating"):
        return (f"{head}, at the {check['outside_bounds']} data point(s) outside the input "
                "bounds, where it extrapolates: widen the bounds and the campaign, or leave "
                "those points out.")
    if worst in check.get("variance_overstated", {}):
        return (f"{head}; but {worst}'s variance is overstated (its leave-one-out errors are "
                "far below its sd at most runs), so more runs are not what it needs: check "
                "it with 'calnet verify'.")
    if worst in check.get("runs_gain_little", ()):
        return (f"{head}; more runs of '{model}' would barely lower it (its GP's variance "
                "hardly falls with runs).")
    runs = " and ".join(f"about {check['runs_needed'][k]} runs of '{k.split('.')[0]}' "
                        f"(now {check['runs'][k]})"
                        for k in check.get("needing_runs", ())) or "more runs"
    return f"{head}; {runs} would bring it to {check.get('target_ratio', 0.25):g} x."


def _sampler_warning(stage: str, s: Mapping[str, Any], cal: CalibrationResult) -> str | None:
    problems = []
    if s["max_rhat"] > cal.rhat_max:
        problems.append(f"max R-hat {rhat_text(s['max_rhat'], cal.rhat_max)} > {cal.rhat_max}")
    if s["min_ess_bulk"] < cal.ess_min:
        problems.append(f"min bulk ESS {s['min_ess_bulk']:.0f} < {cal.ess_min}")
    if s["divergences"]:
        problems.append(f"{s['divergences']} divergent transitions")
    if not problems:
        return None
    advice = []
    if s["max_rhat"] > cal.rhat_max:
        advice.append("raise settings.sampler.warmup and draws; chains that still disagree "
                      "sit in separate modes the data cannot tell apart")
    elif s["min_ess_bulk"] < cal.ess_min:
        advice.append("raise settings.sampler.draws")
    if s["divergences"]:
        advice.append("raise settings.sampler.target_accept (e.g. 0.95)")
    return (f"{stage}: the sampler has not converged ({', '.join(problems)}); "
            f"{'; '.join(advice)}.")


def _warnings(results: RunResults) -> list[str]:
    """Surrogate checks, then sampler problems, calibration notes and the other warnings."""
    cal = results.calibration
    if not cal.calibrated:  # nothing calibrated: no checks, notes or sampler
        return [w for w in results.warnings if not _CONVERGENCE.search(w)]
    checks = {k: c for k, c in cal.surrogate_check.items() if c.get("warning")}
    notes = list(cal.notes)
    out = [_surrogate_warning(k, c) for k, c in checks.items()]
    out += [w for w in (_sampler_warning(k, s, cal) for k, s in sampling_stages(cal.models).items())
            if w]
    out += notes
    known = {c["warning"] for c in checks.values()} | set(notes)
    out += [w for w in results.warnings if w not in known and not _CONVERGENCE.search(w)]
    return out
