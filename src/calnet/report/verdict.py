"""What a comparison of discrepancy variants by leave-one-out says, in a sentence per
variant and data set (the report's validation section and its headline)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from calnet.report.html import fmt

K_RELIABLE = 0.7  # Pareto k above which a PSIS ELPD is not to be trusted
#: an ELPD difference below this is small whatever its standard error: the models predict
#: alike and the normal approximation of the difference's error is unreliable there
#: (Sivula, Magnusson, Matamoros and Vehtari 2022, "Uncertainty in Bayesian leave-one-out
#: cross-validation based model comparison")
ELPD_SMALL = 4.0

_MEANING = {  # what each variant's result says about the spec's discrepancy
    "no_discrepancy": ("the discrepancy is needed",
                       "the data cannot tell whether the discrepancy is needed",
                       "the discrepancy does not help: the model predicts better without it"),
    "non_orthogonal": ("orthogonality helps", "orthogonality makes no clear difference",
                       "the discrepancy predicts better without orthogonality"),
    "reference": ("the spec's discrepancy predicts better than the reference study's",
                  "the spec's and the reference study's discrepancy predict alike",
                  "the reference study's discrepancy predicts better"),
}


def comparison_verdicts(comparison: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """One sentence per data set and variant: which model predicts the left-out points
    better where the ELPD difference exceeds both two standard errors and
    :data:`ELPD_SMALL` (else: no clear difference), what that says about the
    discrepancy, and whether a Pareto k makes it uncertain.

    ``comparison``: ``{data set: {"spec" or variant: VariantScore}}``."""
    out = []
    for name, cmp in comparison.items():
        spec = cmp.get("spec")
        if spec is None:
            continue
        for variant, r in cmp.items():
            if variant == "spec":
                continue
            diff = r.elpd_loo - spec.elpd_loo  # > 0: the variant predicts better
            se = r.dse_spec  # of the difference to the spec's model, from pointwise ELPDs
            if se is None:  # ArviZ's, of each model's difference to the best
                se = r.dse if spec.elpd_diff == 0 else spec.dse if r.elpd_diff == 0 else None
            meaning = _MEANING.get(variant)
            k = max(r.max_pareto_k, spec.max_pareto_k)
            shaky = (f" (Pareto k up to {fmt(k)}: these ELPDs are uncertain)"
                     if k > K_RELIABLE else "")
            size = f"ELPD difference {fmt(abs(diff))}" + (f" ± {fmt(se)}" if se is not None
                                                           else "")
            if se is None or abs(diff) <= 2 * se or abs(diff) < ELPD_SMALL:
                why = ("no standard error of the difference" if se is None
                       else "within two standard errors" if abs(diff) <= 2 * se
                       else f"below {ELPD_SMALL:g}, too small to tell models apart")
                out.append(f"{name}: no clear difference between the spec's model and "
                           f"{variant} ({size}, {why})"
                           + (f"; {meaning[1]}" if meaning else "") + f"{shaky}.")
                continue
            better, worse = (variant, "the spec's model") if diff > 0 else (
                "the spec's model", variant)
            said = f"; {meaning[0] if diff < 0 else meaning[2]}" if meaning else ""
            out.append(f"{name}: {better} predicts the left-out points better than {worse} "
                       f"({size}, more than two standard errors and {ELPD_SMALL:g}){said}{shaky}.")
    return out
