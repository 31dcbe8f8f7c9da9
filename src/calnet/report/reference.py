"""Published results of the reference study (method.md section 7), for comparison."""

from __future__ import annotations

from calnet.report.html import fmt

REFERENCE_MODES = {
    "melt_pool": {"K_S": 68.04, "K_L": 149.75, "K_Lz": 1.29, "K_V": 12.995, "K_Vz": 1361.47,
                  "A_0": 0.34, "A_max": 0.73},
    "solidification": {"sigma": 1.11e-7, "M": 10.02, "p_int": 9107.01},
}
PDAS_TEST_MAPE, PDAS_TEST_SE = 5.7, 0.023


def reference_rows(ctx, summary) -> list[list[str]]:
    """Rows ``[quantity, reference, calnet]`` where the network matches the case study."""
    rows = []
    names = {d.name: d.observes for d in ctx.network.data}
    if names.get("pdas") != "solidification.lambda" and not any(
            m in {x.name for x in ctx.network.models} for m in REFERENCE_MODES):
        return rows
    v = ctx.metrics.get("validation", {}).get("pdas", {})
    if "test" in v:
        rows.append(["PDAS test MAPE %", fmt(PDAS_TEST_MAPE), fmt(v["test"]["mape"])])
        rows.append(["PDAS test SE_pred = RMSE (um)", fmt(PDAS_TEST_SE), fmt(v["test"]["rmse"])])
        base = v.get("baselines_test", {}).get("training_mean", {})
        if base:
            rows.append(["PDAS test MAPE %, training-mean baseline", "6.9", fmt(base["mape"])])
        power = v.get("baselines_test", {}).get("power_law", {})
        if power:
            rows.append(["PDAS test MAPE %, power-law baseline", "6.6", fmt(power["mape"])])
    sens = ctx.metrics.get("sensitivity", {}).get("pdas")
    if sens:
        ind = sens["indices"]
        top = ind["names"][max(range(len(ind["ST"])), key=lambda j: ind["ST"][j])]
        rows.append(["dominant input (total effect)", "v (scan speed)", top])
    for model, modes in REFERENCE_MODES.items():
        params = summary.get(model, {}).get("parameters", {})
        for name, ref in modes.items():
            if name in params:
                rows.append([f"mode {model}.{name}", fmt(ref), fmt(params[name]["mode"])])
    return rows
