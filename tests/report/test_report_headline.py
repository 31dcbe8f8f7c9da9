"""The headline box: estimates, prediction error against the baselines, the warnings
that matter."""

from dataclasses import replace

import numpy as np
from report_inputs import BOUND, ESS, RHAT, calibration, results, summary, validation

from calnet.emulation import OutputSlices
from calnet.report import Headline, Section, write_report
from calnet.report.headline import MAX_WARNINGS, headline
from calnet.results import CalibrationResult


def test_parameters_show_mean_and_interval_with_units():
    box = headline(results())
    params = box.tables[0]
    assert params.header == ("parameter", "posterior mean", "95 % interval", "unit")
    assert params.rows == (("thermal.a", 1.2, "[1.1, 1.3]", "W"),
                           ("s (shared)", 5.0, "[4, 6]", ""),  # once; no unit "1"
                           ("micro.b", 0.8, "[0.7, 0.9]", "um"))
    assert "at their prior (no data): extra" in box.lines[0]


def test_prediction_error_against_the_baselines_on_the_same_points():
    box = headline(results(), units={"width": "um", "hard": "HV"})
    err = box.tables[1]
    assert err.header == ("data set", "evaluated on", "unit", "calnet", "training mean",
                          "direct GP")  # only the baselines the run has
    rows = {r[0]: r for r in err.rows}
    assert rows["width"] == ("width", "10 held-out points", "um", "12.9 (12.3 %)",
                             "44.1 (38.8 %)", "failed")
    # no test split: leave-one-out, against the training mean left out the same way
    assert rows["hard"] == ("hard", "leave-one-out, 8 points", "HV", "2.06 (0.762 %)",
                            "23.6 (10.4 %)", "\u2013")
    assert rows["tiny"][1:4] == ("3 training points (no test)", "", "0.1 (1 %)")
    valid = validation()
    valid["width"].test["mape"] = None  # not meaningful: RMSE alone
    assert headline(results(valid=valid)).tables[1].rows[0][3] == "12.9"


def test_warnings_that_matter_come_first_and_convergence_reads_once():
    cal = calibration(summary(rhat=1.018, ess=178.0, divergences=3))
    box = headline(results([RHAT, ESS, BOUND], cal=cal), warnings_section=7)
    assert box.warnings[0].startswith("pdas: the surrogate, not the data, sets the answer")
    assert "mostly micro.lam" in box.warnings[0] and "552 runs of 'micro' (now 30)" in (
        box.warnings[0])
    assert box.warnings[1] == ("micro: the sampler has not converged (max R-hat 1.018 > "
                               "1.01, min bulk ESS 178 < 400, 3 divergent transitions); "
                               "raise settings.sampler.warmup and draws; chains that still "
                               "disagree sit in separate modes the data cannot tell apart; "
                               "raise settings.sampler.target_accept (e.g. 0.95).")
    assert box.warnings[2:] == (BOUND,)  # the sampler's own messages are not repeated
    assert "see the warnings" in box.lines[1] and "3 divergent" in box.lines[1]
    assert box.more == "The run's 4 warning(s) in full: section 7."


def test_clean_run_says_so_and_long_lists_are_cut():
    clean = replace(results(), warnings=(), calibration=calibration(mode="joint", checks={}))
    box = headline(clean)
    assert box.warnings == () and box.more is None
    assert box.lines[1].endswith("within the limits.")
    many = [f"other warning {i}" for i in range(10)]
    box = headline(results(many), warnings_section=5)
    assert len(box.warnings) == MAX_WARNINGS
    assert box.more.startswith(f"{11 - MAX_WARNINGS} more not shown here.")


def test_headline_box_is_rendered_first(tmp_path):
    box = headline(results([BOUND, "<b>x</b>"]), warnings_section=2)
    html = write_report(tmp_path, title="t", headline=box,
                        sections=[Section("A"), Section("Warnings")]).read_text()
    assert html.index('id="headline"') < html.index("<nav>") < html.index('id="s1"')
    assert "Calibrated parameters" in html and "Prediction error: RMSE (MAPE)" in html
    assert '<li class="warn">&lt;b&gt;x&lt;/b&gt;</li>' in html
    clean = write_report(tmp_path / "c", title="t", sections=[], headline=Headline())
    assert '<p class="ok">No warnings.</p>' in clean.read_text()
    assert 'id="headline"' not in write_report(tmp_path / "n", title="t",
                                               sections=[]).read_text()


def test_emulation_only_and_parameterless_runs_say_what_was_calibrated():
    """No data: no calibration line, the predicted outputs' table instead; data without
    parameters: only the discrepancy and noise were calibrated."""
    arr = lambda *v: (np.array(v),)  # noqa: E731
    sl = OutputSlices("M3.y", ("M1.x",), arr(0.0, 0.5, 1.0), arr(1.0, 2.0, 4.0),
                      arr(0.5, 1.8, 3.0), arr(1.5, 2.2, 5.0), np.array([0.5]),
                      {"emulator M3.y": 1.0})
    none = CalibrationResult(mode="none", plug="-", calibrated=False, models={}, rhat_max=1.01,
                             ess_min=400)
    emulated = replace(results(), warnings=(), validation={}, calibration=none,
                       predicted_outputs={"M3.y": sl})
    box = headline(emulated, predicted_units={"M3.y": "mm"})
    assert box.lines == ("No data sets: emulation only, nothing calibrated; the surrogates "
                         "predict M3.y through the chain.",)
    (table,) = box.tables
    assert table.rows == (("M3.y", "x", "[1, 4]", "1.133", "2", "mm"),)  # widths 1, .4, 2
    (plain,) = headline(emulated, predicted_units={"M3.y": "1"}).tables
    assert plain.rows[0][-1] == ""  # a dimensionless output: no unit "1"
    with_data = replace(emulated, calibration=calibration({}, checks={}))
    assert "no calibration parameters" in headline(with_data).lines[0]


def test_draws_moved_by_upstream_draws_get_their_samplers_advice():
    """Segmented with plugged posterior draws: the stage's R-hat and ESS are its sampler's
    (an upstream stage's own warning covers that stage), so the advice is the sampler's."""
    s = summary(rhat=1.844, ess=3.0)
    s["micro"]["moved_by"] = ["thermal.a"]
    box = headline(results([BOUND], cal=calibration(s)))
    assert box.warnings[1] == ("micro: the sampler has not converged (max R-hat 1.844 > "
                               "1.01, min bulk ESS 3 < 400); raise settings.sampler.warmup "
                               "and draws; chains that still disagree sit in separate modes "
                               "the data cannot tell apart.")


def test_an_r_hat_just_above_the_limit_does_not_read_as_equal_to_it():
    from calnet.results import rhat_text

    assert rhat_text(1.0104) == "1.0104" and rhat_text(1.0184) == "1.018"
    assert rhat_text(1.0096) == "1.010" and rhat_text(1.003) == "1.003"
    box = headline(results([BOUND], cal=calibration(summary(rhat=1.0104, ess=900.0))))
    assert "max R-hat 1.0104 > 1.01" in box.warnings[1]
    assert any("max R-hat 1.0104 (limit 1.01)" in line for line in box.lines), box.lines


def test_a_surrogate_that_extrapolates_to_the_data_names_the_points_not_runs():
    checks = {"pdas": {"ratio": 3.1, "warning": "pdas: ...", "outside_bounds": 2,
                       "outside_share": 0.97, "extrapolating": True,
                       "surrogate_sd": {"micro.lam": 0.5},
                       "runs": {"micro.lam": 30}, "runs_needed": {"micro.lam": 9000}}}
    box = headline(results([], cal=calibration(summary(), checks=checks)), warnings_section=7)
    said = box.warnings[0]  # the surrogate checks come first
    assert "at the 2 data point(s) outside the input bounds" in said and "9000" not in said


def test_influential_points_are_named_by_their_inputs_and_measurement():
    from calnet.report.build import _p, influential_note

    loo = {"k_threshold": 0.7, "influential": [
        {"point": 7, "pareto_k": 3.0, "refit": True, "y": 4.058, "inputs": {"x": 1.0}},
        {"point": 0, "pareto_k": 1.03, "refit": False, "y": 0.1, "inputs": {"x": 0.0}}]}
    note = influential_note("d", loo, "mm")
    assert note.startswith("d: 2 points with Pareto k > 0.7")
    assert "x = 1: 4.058 mm (k = 3, re-calibrated without it); x = 0: 0.1 mm (k = 1.03)" in note
    one = influential_note("d", {**loo, "influential": loo["influential"][:1]}, most=1)
    assert "1 point with" in one and "4.058 (k = 3" in one and "more" not in one
    assert influential_note("d", loo, most=1).endswith("and 1 more.")
    assert _p(float("nan"), "too few points") == "\u2013 (too few points)"
    assert _p(None) == "\u2013" and _p(0.25) == "0.25"


def test_a_model_sampled_in_two_stages_gives_each_stage_its_own_row():
    """Segmented, with M2's shared k sampled in M1's stage: M2 lists both stages, and
    each stage keeps its own data sets and diagnostics (not M1's for 'M1 and M2')."""
    from calnet.report.headline import sampling_stages

    m1 = {"datasets": ["d1"], "divergences": 0, "max_rhat": 1.006, "min_ess_bulk": 488.0}
    m2 = {"datasets": ["d2"], "divergences": 1, "max_rhat": 1.001, "min_ess_bulk": 857.0}
    summary = {"M1": {"stage": "M1", "stages": {"M1": m1}, **m1},
               "M2": {"stage": "M1 and M2", "stages": {"M1": m1, "M2": m2},
                      "datasets": ["d1", "d2"], "divergences": 1, "max_rhat": 1.006,
                      "min_ess_bulk": 488.0},
               "M3": {"prior_only": True}}
    assert sampling_stages(summary) == {"M1": m1, "M2": m2}
