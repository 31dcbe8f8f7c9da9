"""Cheap simulators linear in their parameters, for the exact-posterior tests
(test_exact_posterior.py). Each is a plain function of a dict of inputs and parameters
returning a dict of outputs; the coefficients are module constants so that the tests'
closed forms use the very same numbers.

Network of test 1 (M1 -> M2 through the unmeasurable output u):

    M1: z = Z0 + ZX * x + ZA * a          (measurable, data set D1)
        u = U0 + UX * x + UA * a          (unmeasurable, linked to M2.u)
    M2: y = YU * u + YB * b + YW * w + Y0 (measurable, data set D2)

so that (z, y) is jointly linear in (a, b). Test 2 (one model with a discrepancy):
``y = K0 + KX * x + KT * t``. Test 3 (two parameters, default noise and discrepancy):
``y = P0 + p + q * x``.
"""

VERSION = "exact-1"

Z0, ZX, ZA = 1.0, 2.0, 1.5
U0, UX, UA = 0.5, 1.0, 0.8
Y0, YU, YB, YW = 0.3, 1.2, 1.0, 0.5
K0, KX, KT = 1.0, 0.5, 1.5
P0 = 1.0


def m1(inputs):
    x, a = inputs["x"], inputs["a"]
    return {"z": Z0 + ZX * x + ZA * a, "u": U0 + UX * x + UA * a}


def m2(inputs):
    return {"y": YU * inputs["u"] + YB * inputs["b"] + YW * inputs["w"] + Y0}


def with_discrepancy(inputs):
    return {"y": K0 + KX * inputs["x"] + KT * inputs["t"]}


def two_parameters(inputs):
    return {"y": P0 + inputs["p"] + inputs["q"] * inputs["x"]}


def upstream_parameter(inputs):
    """M1 of test 2b: the parameter's share of test 2's model, passed down the chain."""
    return {"u": KT * inputs["t"] + 0.0 * inputs["x"]}


def downstream_of_parameter(inputs):
    """M2 of test 2b: test 2's model with the parameter's share from upstream."""
    return {"y": K0 + KX * inputs["x"] + inputs["u"]}
