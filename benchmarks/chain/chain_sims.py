"""The three analytic simulators of the chain benchmark (``python:chain_sims:<name>``).

M1: ``w1 = 0.5 + 0.3 sin(2.5 x - 1.2)``, x in [0, 1], so w1 lands in [0.22, 0.79];
M2: ``w2 = tanh((w1 - 0.5) / step) + 0.5 w1``, a step about ``2 step`` wide at w1 = 0.5
(``step`` a simulator option, 0.05 by default);
M3: ``y = w2 exp(-w1) + w1^2``.
"""

from __future__ import annotations

import math

VERSION = "1"


def f1(x: float) -> float:
    return 0.5 + 0.3 * math.sin(2.5 * x - 1.2)


def f2(w1: float, step: float = 0.05) -> float:
    return math.tanh((w1 - 0.5) / step) + 0.5 * w1


def f3(w1: float, w2: float) -> float:
    return w2 * math.exp(-w1) + w1 * w1


def m1(inputs):
    return {"w1": f1(inputs["x"])}


def m2(inputs, step=0.05):
    return {"w2": f2(inputs["w1"], step)}


def m3(inputs):
    return {"y": f3(inputs["w1"], inputs["w2"])}
