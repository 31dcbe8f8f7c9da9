import math


def lin(inputs):
    x, a = inputs["x"], inputs["a"]
    return {"y": a * x + 0.2 * math.sin(3.0 * x)}
