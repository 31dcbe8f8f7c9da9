"""Three cheap analytic simulators for the end-to-end test network (thermal -> micro ->
hardness), with known parameters used to make the synthetic data."""

import math

TRUE = {"a": 1.2, "b": 0.8, "c": 2.0}


def thermal(inputs):
    P, v, a = inputs["P"], inputs["v"], inputs["a"]
    return {"W": 40.0 + a * 60.0 * P / 200.0 / math.sqrt(v),
            "G": 1e6 * (1.0 + 3.0 * v) * (200.0 / P) ** (0.5 * a)}


def micro(inputs):
    return {"lam": inputs["b"] * 300.0 / math.sqrt(inputs["G"]) / inputs["S"] ** 0.25}


def hardness(inputs):
    return {"H": 100.0 + inputs["c"] * 20.0 / math.sqrt(inputs["lam"])}
