"""Pieces of the report's text: the comparison of discrepancy variants says each
variant's notes once, and a quick run's Sobol spread is labelled indicative."""

from calnet.report.build import comparison_tables, quick_spread_note
from calnet.results import VariantScore

NOTE = "M: bulk ESS 179 < 400 for se2_d1; raise settings.sampler.draws"


def score(elpd, notes=()):
    return VariantScore(elpd_loo=elpd, p_loo=1.0, elpd_diff=0.0, dse=0.0, weight=0.5,
                        max_pareto_k=0.4, draws=400, notes=tuple(notes))


def test_a_variants_notes_are_said_once_for_every_data_set():
    comparison = {ds: {"spec": score(10.0), "no_discrepancy": score(11.0, [NOTE]),
                       "non_orthogonal": score(9.0, ["other note"])}
                  for ds in ("d1", "d2", "d3")}
    tables, paragraphs = comparison_tables(comparison)
    assert [t.caption.split(":")[0] for t in tables] == ["d1", "d2", "d3"]
    assert all(NOTE not in t.caption for t in tables)
    assert paragraphs == [f"Notes on the variants compared below: no_discrepancy: {NOTE}; "
                          "non_orthogonal: other note."]
    assert [r[0] for r in tables[0].rows] == ["spec", "no_discrepancy", "non_orthogonal"]


def test_variants_without_notes_add_no_paragraph():
    tables, paragraphs = comparison_tables({"d1": {"spec": score(1.0),
                                                   "reference": score(2.0)}})
    assert len(tables) == 1 and paragraphs == []


def test_a_quick_runs_spread_is_labelled_indicative():
    assert quick_spread_note({"d1": 3, "d2": 3}).startswith(
        "Quick run: the spread of ST over posterior draws comes from 3 posterior draws only, "
        "so it is indicative, not a 95 % interval")
    assert "d1: 3, d2: 5 posterior draws only" in quick_spread_note({"d1": 3, "d2": 5})


def test_the_comparison_says_whether_the_discrepancy_is_needed():
    from dataclasses import replace

    from calnet.report.verdict import comparison_verdicts

    def s(elpd, diff, dse, k=0.4, pair=None):
        return replace(score(elpd), elpd_diff=diff, dse=dse, max_pareto_k=k, dse_spec=pair)

    needed = {"w": {"spec": s(-118.0, 0.0, 0.0), "no_discrepancy": s(-132.2, 14.2, 2.4)}}
    assert comparison_verdicts(needed) == [
        "w: the spec's model predicts the left-out points better than no_discrepancy (ELPD "
        "difference 14.2 ± 2.4, more than two standard errors and 4); the discrepancy is "
        "needed."]
    # within two standard errors, whichever model leads: no verdict on the discrepancy
    for spec, nodisc in ((s(3.24, 0.0, 0.0), s(2.93, 0.31, 0.66)),
                         (s(2.93, 0.31, 0.66), s(3.24, 0.0, 0.0))):
        assert comparison_verdicts({"p": {"spec": spec, "no_discrepancy": nodisc}}) == [
            "p: no clear difference between the spec's model and no_discrepancy (ELPD "
            "difference 0.31 ± 0.66, within two standard errors); the data cannot tell "
            "whether the discrepancy is needed."]
    # the variant best by far, with a Pareto k that makes it uncertain
    worse = {"d": {"spec": s(-40.0, 6.0, 1.5), "no_discrepancy": s(-34.0, 0.0, 0.0, k=1.13)}}
    (v,) = comparison_verdicts(worse)
    assert v.startswith("d: no_discrepancy predicts the left-out points better than the "
                        "spec's model (ELPD difference 6 ± 1.5, more than two standard "
                        "errors and 4); the discrepancy does not help")
    assert v.endswith("(Pareto k up to 1.13: these ELPDs are uncertain).")
    # a third model best: the pair's own standard error (dse_spec), else no claim
    three = {"d": {"reference": s(0.0, 0.0, 0.0), "spec": s(-1.0, 1.0, 0.5),
                   "non_orthogonal": s(-6.0, 6.0, 0.5, pair=0.1)}}
    assert comparison_verdicts(three)[1].startswith(
        "d: the spec's model predicts the left-out points better than non_orthogonal (ELPD "
        "difference 5 ± 0.1, more than two standard errors and 4)")
    # many standard errors, but a difference below 4: too small to tell models apart
    three["d"]["non_orthogonal"] = s(-1.02, 1.02, 0.5, pair=0.001)
    assert ("no clear difference between the spec's model and non_orthogonal (ELPD "
            "difference 0.02 ± 0.001, below 4, too small to tell models apart)"
            in comparison_verdicts(three)[1])
    three["d"]["non_orthogonal"] = s(-1.02, 1.02, 0.5)
    assert "no clear difference" in comparison_verdicts(three)[1]
    assert "no standard error of the difference" in comparison_verdicts(three)[1]
