def linear(inputs, **kw):
    return {"y": float(inputs["c0"] + inputs["c1"] * inputs["x"])}
