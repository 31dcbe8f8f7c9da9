"""Analytic simulators of the three-model chain example (docs/campaigns.md: ``python:``).

M1: x -> w1, a smooth S-curve; M2: w1 -> w2, a sharp tanh step at w1 = 0.5;
M3: (w1, w2) -> y, a smooth quadratic. ``composite(x)`` is the exact answer through the
chain, y = f3(f1(x), f2(f1(x))), for checking predictions.
"""

from __future__ import annotations

import numpy as np

STEEPNESS = 12.0  # of M2's step: its width in w1 is about 2 / STEEPNESS


def f1(x):
    return 0.1 + 0.8 * (3 * x**2 - 2 * x**3)


def f2(w1):
    return np.tanh(STEEPNESS * (w1 - 0.5))


def f3(w1, w2):
    return w1 * (1 + w2) + 0.25 * w2**2


def composite(x):
    """The chain's exact output y at x (any shape)."""
    w1 = f1(np.asarray(x, dtype=float))
    return f3(w1, f2(w1))


def m1(inputs: dict) -> dict:
    return {"w1": float(f1(inputs["x"]))}


def m2(inputs: dict) -> dict:
    return {"w2": float(f2(inputs["w1"]))}


def m3(inputs: dict) -> dict:
    return {"y": float(f3(inputs["w1"], inputs["w2"]))}
