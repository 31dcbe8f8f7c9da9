"""Tests of M2, the solidification simulator, against physics.md section M2."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.stats import qmc

from calnet.simulators import solidification as m2
from calnet.simulators.base import SimResult

C = m2.CONSTANTS
# physics.md M2 worked check
WORKED = {"S": 0.3, "G": 1e7, "sigma": 2e-6, "M": 7.5, "p_int": 15000.0}
NAMES = m2.INPUTS + m2.PARAMETERS
REFERENCE_BOX = dict(m2.BOUNDS)
# What an M1 (melt pool) campaign over the experimental settings may feed M2: wider S, G.
WIDE_BOX = {**m2.BOUNDS, "S": (0.04, 2.4), "G": (1e5, 5e7)}


def run(variant: str = "A", **overrides: float) -> dict[str, np.ndarray]:
    return m2.simulate_batch(**{**WORKED, **overrides}, variant=variant)


# --- interface -----------------------------------------------------------------------


def test_declared_interface_is_consistent():
    assert m2.NAME == "solidification"
    assert set(m2.UNITS) == set(NAMES + m2.OUTPUTS)
    assert set(m2.BOUNDS) == set(NAMES)
    assert all(lo < hi for lo, hi in m2.BOUNDS.values())
    assert m2.UNITS["sigma"] == "J/cm^2" and m2.UNITS["lambda"] == "um"
    out = run()
    assert set(m2.OUTPUTS) <= set(out)
    assert {"Gamma", "V_D", "dT0_V", "V_a", "dT_k"} <= set(out)


def test_constants_are_frozen_and_dS_v_matches_its_source():
    with pytest.raises(dataclasses.FrozenInstanceError):
        C.k_e = 0.5  # type: ignore[misc]
    # dS_v = rho L_f / T_m: 8900 kg/m^3 * 2.98e5 J/kg / 1728 K (pure Ni)
    assert C.dS_v == pytest.approx(8900 * 2.98e5 / 1728, rel=1e-3)
    assert C.k_e == pytest.approx(0.6875, abs=1e-12)


# --- worked check, physics.md M2 -------------------------------------------------------


@pytest.mark.parametrize(
    ("key", "expected", "tol"),
    [
        ("Gamma", 1.30e-8, 0.005e-8),  # K m
        ("V_D", 3.08, 0.005),  # m/s
        ("k_V", 0.715, 0.0005),
        # exact value 13.143; physics.md's 13.2 follows from k_V rounded to 0.715
        ("dT0_V", 13.2, 0.1),  # K
        ("lambda", 0.27, 0.005),  # um
    ],
)
def test_worked_check(key, expected, tol):
    assert abs(float(run()[key]) - expected) <= tol


def test_worked_point_is_cellular():
    out = run()
    assert not out["planar"]
    assert float(out["V_a"]) > WORKED["S"]


# --- units ---------------------------------------------------------------------------


def test_unit_conversion_factors():
    # 1 J/cm^2 = 1e4 J/m^2; 1 cm^4 = 1e-8 m^4; 1 cm^3 = 1e-6 m^3
    assert m2.TO_SI == {"sigma": 1e4, "M": 1e-8, "p_int": 1e-6}
    sig, mob, perm = m2.parameters_to_si(2e-6, 7.5, 15000.0)
    assert float(sig) == pytest.approx(2e-2)
    assert float(mob) == pytest.approx(7.5e-8)
    assert float(perm) == pytest.approx(1.5e-2)


def test_intermediate_quantities_carry_si_units():
    out = m2.simulate_batch(1.0, 1e7, 1.0, 1.0, 1.0)
    assert float(out["Gamma"]) == pytest.approx(1e4 / C.dS_v)  # K m from 1 J/cm^2
    assert float(out["V_D"]) == pytest.approx(1e-6 * C.eta * C.f_pp / 8)  # m/s
    assert float(out["dT_k"]) == pytest.approx(1.0 / (1e-8 * C.dS_v))  # K at V = 1 m/s


def test_lambda_is_in_micrometres():
    out = run()
    lam_m = (C.kf_prefactor * (out["dT0_V"] * C.D_l * out["Gamma"] / out["k_V"]) ** 0.25
             * 0.3**-0.25 * 1e7**-0.5 * out["kinetic_factor"])
    assert float(out["lambda"]) == pytest.approx(1e6 * float(lam_m), rel=1e-12)


# --- limits and scaling ---------------------------------------------------------------


@pytest.mark.parametrize("variant", m2.VARIANTS)
def test_k_V_limits(variant):
    slow = run(variant, S=1e-9)
    assert float(slow["k_V"]) == pytest.approx(C.k_e, abs=1e-8)
    v_d = float(slow["V_D"])
    fast = run(variant, S=1e4 * v_d)
    assert float(fast["k_V"]) == pytest.approx(1.0, abs=1e-4)
    # Aziz: 1 - k_V = (1 - k_e) / (1 + V / V_D)
    assert 1 - float(fast["k_V"]) == pytest.approx((1 - C.k_e) / (1 + 1e4), rel=1e-6)
    k = run(variant, S=np.geomspace(1e-3, 100, 50))["k_V"]
    assert np.all(np.diff(k) > 0)


@pytest.mark.parametrize("variant", m2.VARIANTS)
@pytest.mark.parametrize("speed", [0.05, 0.3, 2.0])
def test_lambda_scales_as_G_to_minus_one_half(variant, speed):
    G = np.geomspace(1e5, 5e7, 9)
    lam = run(variant, S=speed, G=G)["lambda"]
    np.testing.assert_allclose(lam * np.sqrt(G), lam[0] * np.sqrt(G[0]), rtol=1e-12)


def log_sensitivities(variant: str, h: float = 1e-4) -> dict[str, float]:
    """d ln lambda / d ln x at the worked point, central differences in log space."""
    sens = {}
    for name in NAMES:
        up = run(variant, **{name: WORKED[name] * np.exp(h)})["lambda"]
        down = run(variant, **{name: WORKED[name] * np.exp(-h)})["lambda"]
        sens[name] = float(np.log(up / down)) / (2 * h)
    return sens


def test_log_sensitivities_match_physics_md():
    expected = {"S": -0.44, "G": -0.50, "sigma": 0.25, "M": 0.12, "p_int": 0.05}
    sens = log_sensitivities("A")
    for name, value in expected.items():
        assert abs(sens[name] - value) <= 0.02, (name, sens[name])


def test_variant_B_log_sensitivities():
    # No kinetic factor: M drops out; Gamma and G enter only through the KF power laws.
    sens = log_sensitivities("B")
    assert sens["M"] == 0.0
    assert sens["G"] == pytest.approx(-0.5, abs=1e-6)
    assert sens["sigma"] == pytest.approx(0.25, abs=1e-6)
    assert abs(sens["p_int"]) < 0.02  # even weaker than in variant A
    assert abs(sens["S"] - (-0.44)) <= 0.02


# --- planar fronts -------------------------------------------------------------------


def test_kinetic_floor_flags_planar_and_keeps_lambda_finite():
    # M 4, p_int 5000, V 0.6: dT_k = 9.8 K exceeds 0.95 dT0_V = 7.8 K
    out = run(S=0.6, M=4.0, p_int=5000.0)
    assert out["planar"] and out["planar_kinetic"] and not out["planar_absolute"]
    assert float(out["kinetic_factor"]) == pytest.approx(np.sqrt(C.kinetic_floor))
    assert np.isfinite(out["lambda"]) and float(out["lambda"]) > 0


def test_absolute_stability_flags_planar():
    out = run("B", S=2.0)  # variant B at the worked parameters: V_a = 1.25 m/s
    assert float(out["V_a"]) < 2.0
    assert out["planar"] and out["planar_absolute"] and not out["planar_kinetic"]
    assert np.isfinite(out["lambda"])


@pytest.mark.parametrize("variant", m2.VARIANTS)
def test_lambda_is_continuous_across_the_planar_boundary(variant):
    S = np.linspace(0.05, 3.0, 20001)  # step 1.5e-4 m/s
    out = run(variant, S=S, M=4.0, p_int=5000.0)
    assert out["planar"].any() and not out["planar"].all()
    jumps = np.abs(np.diff(np.log(out["lambda"])))
    assert jumps.max() < 1e-2  # smooth curve: no step at the flag


# --- whole-box sweeps -----------------------------------------------------------------


def lhs(box: dict[str, tuple[float, float]], n: int, seed: int) -> dict[str, np.ndarray]:
    unit = qmc.LatinHypercube(d=len(NAMES), seed=seed).random(n)
    lo = np.array([box[k][0] for k in NAMES])
    hi = np.array([box[k][1] for k in NAMES])
    x = qmc.scale(unit, lo, hi)
    return {k: x[:, i] for i, k in enumerate(NAMES)}


@pytest.mark.parametrize("variant", m2.VARIANTS)
@pytest.mark.parametrize("box_name", ["reference", "wide"])
def test_sweep_has_no_nan_and_reports_planar_share(variant, box_name):
    box = REFERENCE_BOX if box_name == "reference" else WIDE_BOX
    out = m2.simulate_batch(**lhs(box, n=4096, seed=0), variant=variant)
    planar = out["planar"]
    for key, value in out.items():
        assert np.all(np.isfinite(value[~planar])), key
        assert np.all(np.isfinite(value)), key  # the floor keeps planar cases finite too
    assert np.all(out["lambda"] > 0)
    assert np.all((out["k_V"] > C.k_e) & (out["k_V"] < 1))
    share = float(planar.mean())
    print(f"\nM2 variant {variant}, {box_name} box: planar share {share:.2%} "
          f"(absolute {out['planar_absolute'].mean():.2%}, "
          f"kinetic floor {out['planar_kinetic'].mean():.2%})")
    # Reference box: almost all cellular (variant A only at the M-low, p_int-low corner).
    if box_name == "reference":
        assert share < (0.01 if variant == "A" else 0.15)


# --- simulate() ----------------------------------------------------------------------


def test_simulate_worked_point():
    res = m2.simulate(WORKED)
    assert isinstance(res, SimResult)
    assert res.status == "ok" and res.message == ""
    assert res.outputs["lambda"] == pytest.approx(float(run()["lambda"]), rel=1e-12)
    assert res.outputs["planar"] == 0.0
    assert res.diagnostics["planar"] is False
    json.dumps(res.diagnostics)


def test_simulate_defaults_parameters_to_mid_bounds():
    res = m2.simulate({"S": 0.3, "G": 1e7})
    mids = {k: 0.5 * sum(m2.BOUNDS[k]) for k in m2.PARAMETERS}
    assert res.diagnostics["parameters"]["p_int"] == 17500.0
    expected = m2.simulate_batch(0.3, 1e7, **mids)
    assert res.outputs["lambda"] == pytest.approx(float(expected["lambda"]), rel=1e-12)


def test_simulate_planar_is_reported_not_failed():
    res = m2.simulate({**WORKED, "S": 0.6, "M": 4.0, "p_int": 5000.0})
    assert res.status == "ok"
    assert res.outputs["planar"] == 1.0 and res.diagnostics["planar"] is True
    assert "kinetic factor" in res.diagnostics["planar_reason"]
    assert np.isfinite(res.outputs["lambda"])


def test_simulate_missing_input_is_an_error():
    with pytest.raises(ValueError, match=r"missing control inputs \['G'\]"):
        m2.simulate({"S": 0.3})


def test_simulate_unknown_key_is_an_error():
    with pytest.raises(ValueError, match="unknown inputs"):
        m2.simulate({**WORKED, "Sigma": 1e-6})


@pytest.mark.parametrize(
    ("key", "value"), [("S", 0.0), ("G", -1e7), ("sigma", 0.0), ("M", -1.0),
                       ("p_int", float("nan"))])
def test_simulate_non_physical_input_fails_without_exception(key, value):
    res = m2.simulate({**WORKED, key: value})
    assert res.status == "failed"
    assert key in res.message and "> 0" in res.message


def test_unknown_variant_is_rejected():
    with pytest.raises(ValueError, match="variant"):
        m2.simulate_batch(0.3, 1e7, 2e-6, 7.5, 15000.0, variant="C")
    with pytest.raises(ValueError, match="variant"):
        m2.simulate(WORKED, variant="a")


def test_simulate_batch_broadcasts_like_pointwise_calls():
    S = np.array([[0.1], [0.3], [0.9]])
    G = np.array([4e6, 1e7])
    out = m2.simulate_batch(S, G, 2e-6, 7.5, 15000.0)
    assert out["lambda"].shape == out["planar"].shape == out["Gamma"].shape == (3, 2)
    assert out["planar"].dtype == bool
    for i in range(3):
        for j in range(2):
            point = m2.simulate({**WORKED, "S": S[i, 0], "G": G[j]})
            assert out["lambda"][i, j] == pytest.approx(point.outputs["lambda"], rel=1e-12)


@pytest.mark.parametrize(("option", "message"), [
    ("colour=red", "'solidification' has no option ['colour']; it takes ['variant']"),
    ("variant=Z", "variant must be one of"),
])
def test_cli_simulate_bad_option_is_a_user_error(option, message):
    from typer.testing import CliRunner

    from calnet.cli import app

    result = CliRunner().invoke(app, ["simulate", "solidification", "--option", option])
    assert result.exit_code == 2, result.output  # a bad option value: a usage error
    assert "internal error" not in result.output and message in result.output
