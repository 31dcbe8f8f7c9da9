"""Tests of the phase-field M2 (``builtin:phase_field``) against closed forms, SciPy and
the sharp-interface planar steady state."""

from __future__ import annotations

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from typer.testing import CliRunner

from calnet.cli import app
from calnet.simulators import phase_field, solidification
from calnet.simulators.phase_field import model, outputs, solver
from calnet.simulators.phase_field.options import PhaseFieldOptions
from calnet.simulators.registry import builtin_info

C = model.CONSTANTS
WORKED = {"S": 0.3, "G": 1e7, "sigma": 2e-6, "M": 7.5, "p_int": 15000.0}  # physics.md
TINY = {"nx": 24, "ny": 32, "max_steps": 300}


# --- thermodynamics and kinetics -------------------------------------------------------


def test_free_energies_reproduce_k_e_and_the_liquidus_slope():
    xl = np.array([0.02, 0.032, 0.045])
    mu_s, mu_l = model.chemical_potentials(C.k_e * xl, xl, C)
    np.testing.assert_allclose(mu_s, mu_l, rtol=1e-12)  # x_s = k_e x_l is equilibrium
    # at equal chemical potentials dG is dS_v (T - T_liquidus(x_l)), m_l = -10.3 K/at%
    T = np.array([1690.0, 1700.0, 1650.0])
    dG = model.driving_force(0.3, C.k_e * xl, xl, T, C)
    liquidus = C.T0 - 10.3 * (xl * 100 - 3.2)
    np.testing.assert_allclose(dG, C.dS_v * (T - liquidus), rtol=1e-9, atol=1e-3)


def test_driving_force_is_blind_to_a_common_linear_free_energy_term():
    # adding b x to both free energies shifts both mu by b: dG must not change
    xs, xl, T, phi = 0.025, 0.04, 1685.0, 0.4
    mu_s, mu_l = model.chemical_potentials(xs, xl, C)
    b = 3e7
    f_s = C.A * (xs * np.log(xs) - xs - xs * np.log(C.k_e)) + C.dS_v * (T - C.T_m) + b * xs
    f_l = C.A * (xl * np.log(xl) - xl) + b * xl
    shifted = f_s - f_l - (phi * (mu_s + b) + (1 - phi) * (mu_l + b)) * (xs - xl)
    assert float(model.driving_force(phi, xs, xl, T, C)) == pytest.approx(float(shifted),
                                                                          rel=1e-9)


def test_kinetic_coefficient_is_eq_4():
    mu, P = 7.5e-8, 0.015
    k = float(model.kinetic_coefficient(0.022, 0.032, mu, P, C))
    assert k == pytest.approx(8 * P * C.eta * mu / (8 * P * C.eta + mu * math.pi**2 * 1e-4))
    assert float(model.kinetic_coefficient(0.03, 0.03, mu, P, C)) == pytest.approx(mu)


def test_exchange_step_matches_the_ode_and_conserves_solute():
    phi, xs, xl, P = 0.4, 0.030, 0.034, 0.015

    def rhs(_, y):
        mu_s, mu_l = (C.A * np.log(y[0] / C.k_e), C.A * np.log(y[1]))
        return [P * (1 - phi) * (mu_l - mu_s), -P * phi * (mu_l - mu_s)]

    dt = 5e-10  # 1.5 decay times of the exchange: explicit Euler would overshoot
    ref = solve_ivp(rhs, (0, dt), [xs, xl], method="Radau", rtol=1e-10, atol=1e-14).y[:, -1]
    ex = float(model.exchange_integral(phi, xs, xl, P, dt, C))
    got = np.array([xs + (1 - phi) * ex, xl - phi * ex])
    np.testing.assert_allclose(got, ref, rtol=2e-3)
    assert phi * got[0] + (1 - phi) * got[1] == pytest.approx(phi * xs + (1 - phi) * xl,
                                                              rel=1e-14)


def test_one_step_conserves_the_mixture_in_a_periodic_box():
    rng = np.random.default_rng(3)
    phi = jnp.asarray(np.clip(rng.uniform(-0.3, 1.3, (16, 16)), 0, 1))
    xs = jnp.asarray(rng.uniform(0.02, 0.03, (16, 16)))
    xl = xs / C.k_e * rng.uniform(0.95, 1.05, (16, 16))
    T = jnp.full((16, 16), 1690.0)
    new = model.step(phi, xs, xl, T, 0.02, 7.5e-8, 0.015, 1e-9, 5e-9, C)
    # no-flux in y and periodic in x: the total solute only changes by the bulk resets,
    # which touch the absent phase alone
    mix = [float(jnp.sum(p * s + (1 - p) * lq)) for p, s, lq in ((phi, xs, xl), new)]
    assert mix[1] == pytest.approx(mix[0], rel=1e-12)


def _slab(n: int, dx: float) -> np.ndarray:
    """A solid slab across the middle of ``n`` cells with sine-profile edges, ``(n,)``."""
    z = (np.arange(n) + 0.5) * dx
    d = np.abs(z - 0.5 * n * dx) - 0.25 * n * dx  # distance outside the slab
    return 0.5 * (1.0 - np.sin(np.clip(d / C.eta, -0.5, 0.5) * np.pi))


def test_anti_trapping_flux_is_the_one_sided_normal_flux_and_rotates():
    dx, n = 5e-9, 48
    phi = _slab(n, dx)
    rng = np.random.default_rng(5)
    xs = rng.uniform(0.02, 0.03, n)
    xl = xs / C.k_e
    rate = rng.uniform(1e6, 2e6, n)
    # plain 1D loop: face flux a eta (x_l - x_s)(1 - phi) phi_t n, n = -sign(dphi)
    g = (xl - xs) * (1 - phi) * rate
    flux = np.zeros(n + 1)  # flux[j] through the face below cell j; no flux at the ends
    for j in range(1, n):
        d = phi[j] - phi[j - 1]
        flux[j] = 0.0 if d == 0 else -np.sign(d) * 0.5 * C.eta * 0.5 * (g[j] + g[j - 1])
    want = -(flux[1:] - flux[:-1]) / dx
    col = [jnp.asarray(np.tile(a[:, None], (1, 3))) for a in (phi, rate, xs, xl)]
    got = np.asarray(model.antitrapping_divergence(*col, 0.5, dx, C))
    np.testing.assert_allclose(got, np.tile(want[:, None], (1, 3)), rtol=1e-12,
                               atol=1e-12 * np.abs(want).max())
    # the same slab across x (periodic) gives the transposed field; the total is zero
    row = [a.T for a in col]
    np.testing.assert_allclose(np.asarray(model.antitrapping_divergence(*row, 0.5, dx, C)),
                               got.T, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    assert abs(got.sum()) < 1e-12 * np.abs(got).sum()


# --- measuring the front ---------------------------------------------------------------


def test_front_heights_and_dominant_mode_on_a_known_profile():
    dx, nx, ny = 5e-9, 120, 80
    x = np.arange(nx) * dx
    h = 200e-9 + 20e-9 * np.cos(2 * np.pi * 4 * x / (nx * dx))
    y = (np.arange(ny) + 0.5) * dx
    phi = np.clip(0.5 - (y[:, None] - h[None, :]) / (4 * dx), 0, 1)  # linear, 4 cells
    got = outputs.front_heights(phi, y)
    np.testing.assert_allclose(got, h, atol=1e-12)
    mode, amp = outputs.dominant_mode(got, dx)
    assert mode == 4 and amp == pytest.approx(20e-9, rel=1e-9)
    assert outputs.dominant_mode(np.full(nx, 1e-7), dx)[0] == 0


def _cell_array(edges, tips, *, dx, ny, groove_cells=2, groove_phi=0.7):
    """A synthetic cell array ``(ny, nx)`` and its heights: cells between the periodic
    ``edges`` (column indices), each a parabolic cap topped at ``tips[i]`` (m) and 10 nm
    lower at its sides, separated by grooves ``groove_cells`` wide that open 60 nm below
    the lowest tip and hold ``phi = groove_phi`` below that (a narrow groove of a diffuse
    interface never reaches ``phi = 0``); sine profiles of width eta along y."""
    nx = edges[-1] - edges[0]
    top = np.empty(nx)
    groove = np.zeros(nx, dtype=bool)
    for i, (a, b) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        cols = np.arange(a, b)
        half = 0.5 * (b - a) * dx
        xc = (cols + 0.5) * dx - a * dx - half
        top[cols % nx] = tips[i] - 10e-9 * (xc / half) ** 2
        groove[np.arange(b - groove_cells, b) % nx] = True
    top[groove] = min(tips) - 60e-9
    y = (np.arange(ny) + 0.5) * dx
    arg = np.clip((y[:, None] - top[None, :]) / C.eta, -0.5, 0.5) * np.pi
    phi = 0.5 * (1.0 - np.sin(arg))
    phi[:, groove] = np.minimum(phi[:, groove], groove_phi)
    return phi, y


def test_grooves_counts_runs_of_not_fully_solid_cells_around_the_period():
    assert outputs.grooves(np.array([1, 1, 0.5, 1, 1, 0.2, 0.3, 1.0])) == 2
    assert outputs.grooves(np.array([0.5, 1, 1, 0.9])) == 1  # one groove across the seam
    assert outputs.grooves(np.ones(8)) == 0
    assert outputs.grooves(np.full(8, 0.99)) is None  # no solid: cannot separate cells


def test_cell_count_counts_cells_whose_tips_are_modulated_at_another_wavelength():
    # 23 cells of uneven width (seeded), tips 30 nm high modulated over 7 periods: the
    # front height sees the modulation, the count behind the tips sees the 23 cells
    dx, nx, ny, n = 5e-9, 384, 128, 23
    rng = np.random.default_rng(11)
    widths = rng.multinomial(nx - 10 * n, np.full(n, 1 / n)) + 10
    edges = np.concatenate([[0], np.cumsum(widths)]) + 5  # cells also cross the seam
    centres = 0.5 * (edges[:-1] + edges[1:]) / nx
    tips = 0.45e-6 + 15e-9 * np.cos(2 * np.pi * 7 * centres)
    phi, y = _cell_array(edges, tips, dx=dx, ny=ny)
    h = outputs.front_heights(phi, y)
    assert outputs.dominant_mode(h, dx)[0] == 7
    tip = float(h.max())
    assert outputs.cell_count(phi, y, tip, C.eta) == n
    # rows just behind the leading tip cut above the lagging ones and merge grooves
    assert outputs.cell_count(phi, y, tip, C.eta, band=(0.6, 1.0)) < n
    st = outputs.measure(phi, phi * 0 + 0.02, phi * 0 + 0.03, y=y, t=1e-6, dx=dx,
                         eta=C.eta, temperature_at=lambda yy, tt: 1690.0, T0=1695.0)
    assert st.cells == n and st.spacing == pytest.approx(nx * dx / n, rel=1e-12)
    assert st.mode == 7


def test_cell_count_of_a_flat_front_and_of_a_single_cell():
    dx, nx, ny = 5e-9, 64, 96
    y = (np.arange(ny) + 0.5) * dx
    flat = 0.5 * (1.0 - np.sin(np.clip((y - 0.3e-6) / C.eta, -0.5, 0.5) * np.pi))
    phi = np.tile(flat[:, None], (1, nx))
    assert outputs.cell_count(phi, y, 0.3e-6, C.eta) == 0
    one, _ = _cell_array(np.array([0, nx]), np.array([0.35e-6]), dx=dx, ny=ny)
    assert outputs.cell_count(one, y, 0.35e-6, C.eta) == 1


def _history(cells, *, dt=1e-7, speed=0.3, du=12.0):
    """States every ``dt`` with the given cell counts, moving at ``speed``."""
    return [outputs.FrontState(t=i * dt, tip=speed * i * dt, undercooling=du, k_V=0.7,
                               cells=c, spacing=1e-7, mode=c, wavelength=1e-7,
                               amplitude=1e-8) for i, c in enumerate(cells)]


def test_steady_needs_the_same_mean_cell_count_over_the_whole_window():
    kw = {"speed": 0.3, "min_time": 2e-6, "window_time": 1e-6}  # window: last 11 states
    assert outputs.steady(_history([30] * 10 + [24] * 21), **kw)
    assert outputs.steady(_history([30] * 10 + [24, 25, 23, 24, 26] * 4 + [24]), **kw)
    assert not outputs.steady(_history([30] * 25 + [24] * 6), **kw)  # coarsened inside
    assert not outputs.steady(_history([24] * 26 + [22] * 5), **kw)  # lost 2 of 24 cells
    assert not outputs.steady(_history([0] * 24 + [3] * 7), **kw)  # cells appeared
    assert not outputs.steady(_history([24] * 11), **kw)  # too short a run
    assert not outputs.steady(_history([24] * 31, speed=0.285), **kw)  # 5 % too slow
    hist = _history([24] * 31)
    hist[-3] = outputs.FrontState(**{**hist[-3].to_dict(), "undercooling": 14.0})
    assert not outputs.steady(hist, **kw)  # the undercooling jumped by 2 K


def test_tip_partition_reads_x_l_at_the_half_crossing():
    phi = np.array([1.0, 1.0, 1.0, 0.8, 0.3, 0.0, 0.0])
    xs = np.array([0.030, 0.031, 0.032, 0.033, 0.034, 0.035, 0.036])
    xl = np.array([0.044, 0.045, 0.046, 0.047, 0.042, 0.038, 0.034])
    # phi = 1/2 lies 3/5 of the way from cell 3 to cell 4: x_l = 0.047 - 0.6 * 0.005
    assert outputs._tip_partition(phi, xs, xl) == pytest.approx(0.032 / 0.044, rel=1e-12)


# --- the solver ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def planar_runs():
    # four freezing-range lengths: at 0.6 m/s the undercooling still creeps after two
    opts = PhaseFieldOptions(nx=1, ny=96, amplitude=0.0, max_steps=30000, window=24,
                             min_travel=4.0)
    return {S: solver.run(phase_field.parameters({**WORKED, "S": S}), opts)
            for S in (0.3, 0.6)}


@pytest.mark.parametrize("S", [0.3, 0.6])
def test_flat_front_reaches_the_planar_steady_state(planar_runs, S):
    rec = planar_runs[S]
    assert rec.status == "steady"
    s = outputs.summary(rec.history, 24)
    assert s["tip_speed"] == pytest.approx(S, rel=0.02)
    # mass balance of a steady planar front: the solid left behind has the alloy's c0
    phi, xs, xl = (rec.fields[k][:, 0] for k in ("phi", "xs", "xl"))
    frozen = xs[: np.argmax(phi < 1.0) - 4]
    np.testing.assert_allclose(frozen[-20:], C.c0, rtol=5e-3)
    # trapping: Aziz's continuous growth model with V_D from the permeability, the
    # closed-form solidification M2 (variant A), within 5 %
    aziz = solidification.simulate_batch(**{**WORKED, "S": S})["k_V"]
    assert s["k_V"] == pytest.approx(float(aziz), rel=0.05)
    assert C.k_e < s["k_V"] < 1


def test_without_the_anti_trapping_current_the_diffuse_interface_traps():
    # the first-order thin-interface excess of x_l across the solid half of the interface,
    # (1 - k_e) V eta / (2 D_l) = 31 % at 0.3 m/s, is what the current removes
    opts = PhaseFieldOptions(nx=1, ny=96, amplitude=0.0, max_steps=30000, window=24,
                             min_travel=2.0, antitrapping=0.0)
    rec = solver.run(phase_field.parameters(WORKED), opts)
    k_v = outputs.summary(rec.history, 24)["k_V"]
    aziz = float(solidification.simulate_batch(**WORKED)["k_V"])
    assert k_v > 1.1 * aziz


def test_same_seed_same_result_other_seed_other_result():
    p = phase_field.parameters(WORKED)
    a, b, c = (solver.run(p, PhaseFieldOptions(seed=s, **TINY)) for s in (1, 1, 2))
    np.testing.assert_array_equal(a.fields["phi"], b.fields["phi"])
    np.testing.assert_array_equal(a.fields["xl"], b.fields["xl"])
    assert not np.array_equal(a.fields["phi"], c.fields["phi"])


def test_an_unstable_step_is_a_failed_run_not_a_traceback(monkeypatch):
    monkeypatch.setattr(solver, "stable_time_step", lambda *a, **k: 1e-7)  # 60x too big
    res = phase_field.simulate(WORKED, **TINY)
    assert res.status == "failed" and "diverged" in res.message
    assert all(math.isnan(v) for v in res.outputs.values())


def test_budget_exhausted_is_nonconverged_with_a_reason():
    res = phase_field.simulate(WORKED, **TINY)
    assert res.status == "nonconverged" and "max_steps" in res.message
    assert res.outputs["steady"] == 0.0 and res.diagnostics["steps"] == TINY["max_steps"]


@pytest.mark.parametrize("inputs, match", [
    ({"S": 0.3}, "missing control inputs"),
    ({"S": 0.3, "G": 1e7, "sigmaa": 1.0}, "unknown inputs"),
])
def test_bad_input_names_name_the_problem(inputs, match):
    with pytest.raises(ValueError, match=match):
        phase_field.simulate(inputs, **TINY)


@pytest.mark.parametrize("inputs", [{"S": -0.3, "G": 1e7}, {"S": 0.3, "G": float("nan")}])
def test_a_value_the_model_cannot_take_is_a_failed_run(inputs):
    res = phase_field.simulate(inputs, **TINY)
    assert res.status == "failed" and "must be finite and > 0" in res.message
    assert all(math.isnan(v) for v in res.outputs.values())


def test_bad_options_name_the_problem():
    with pytest.raises(ValueError, match="unknown phase_field options"):
        phase_field.simulate(WORKED, resolutoin="fine")
    with pytest.raises(ValueError, match="resolution must be one of"):
        phase_field.simulate(WORKED, resolution="coarse")
    with pytest.raises(ValueError, match="steady_travel > 0"):
        phase_field.simulate(WORKED, steady_travel=0)


def test_the_resolutions_cover_one_domain_for_one_simulated_time():
    # the presets differ only in the grid: the same 1.92 x 0.64 um domain, and a step
    # budget that buys the same simulated time at each grid's stable step (dt ~ dx^2)
    base = PhaseFieldOptions()
    dt0 = model.stable_time_step(2e-2, 7.5e-8, base.dx, C)
    for name in phase_field.RESOLUTIONS:
        o = PhaseFieldOptions(resolution=name)
        assert o.nx * o.dx == pytest.approx(1.92e-6) and o.ny * o.dx == pytest.approx(0.64e-6)
        dt = model.stable_time_step(2e-2, 7.5e-8, o.dx, C)
        assert o.max_steps * dt == pytest.approx(base.max_steps * dt0)


def test_every_preset_starts_from_the_same_front():
    # the perturbation is drawn per 5 nm noise cell, so a finer grid of the same domain
    # holds the default grid's front, each height repeated over the cells it covers; on
    # the default grid every cell has its own draw (the per-cell noise of a seed)
    c = model.CONSTANTS
    base = PhaseFieldOptions(seed=3)
    _, _, _, y0 = solver.initial_fields(base, c, 0.3)
    h0 = base.amplitude * base.dx * np.random.default_rng(3).uniform(-1.0, 1.0, base.nx)
    np.testing.assert_array_equal(
        solver.front_noise(np.random.default_rng(3), base.nx, base.dx, base.noise_cell, 1.0),
        h0)
    for name, k in (("fine", 2), ("xfine", 4)):
        o = PhaseFieldOptions(resolution=name, seed=3)
        h = solver.front_noise(np.random.default_rng(3), o.nx, o.dx, o.noise_cell, 1.0)
        np.testing.assert_allclose(h, np.repeat(h0, k), rtol=1e-12)
        # and the phase field built on it: the front crosses phi = 1/2 at y0 + h
        phi, _, _, y_front = solver.initial_fields(o, c, 0.3)
        assert y_front == pytest.approx(y0)
        y = (np.arange(o.ny) + 0.5) * o.dx
        col = np.argmax(np.abs(h))
        i = np.nonzero(phi[:, col] >= 0.5)[0].max()  # last solid-side row
        assert y[i] <= y_front + h[col] <= y[i + 1]
    # a grid that does not divide the noise cells still gets the same heights per place
    h = solver.front_noise(np.random.default_rng(3), 500, 1.92e-6 / 500, 5e-9, 1.0)
    x = (np.arange(500) + 0.5) * 1.92e-6 / 500 / 5e-9  # column centres, in noise cells
    inside = np.abs(x - np.round(x)) > 1e-6  # centres on a noise cell's edge: either side
    np.testing.assert_allclose(h[inside], h0[np.floor(x[inside]).astype(int)], rtol=1e-12)


def test_an_initial_cell_count_seeds_a_cosine_array():
    o = PhaseFieldOptions(seed=1, initial_cells=24)
    phi, *_ = solver.initial_fields(o, model.CONSTANTS, 0.3)
    h = outputs.front_heights(phi, (np.arange(o.ny) + 0.5) * o.dx)
    mode, _ = outputs.dominant_mode(h - h.mean(), o.dx)
    assert mode == 24
    with pytest.raises(ValueError, match="initial_cells must be in"):
        PhaseFieldOptions(initial_cells=200)
    with pytest.raises(ValueError, match="noise_cell > 0"):
        PhaseFieldOptions(noise_cell=0.0)


def test_registered_and_runs_from_the_cli():
    info = builtin_info("phase_field")
    assert info.outputs == phase_field.OUTPUTS and info.bounds == solidification.BOUNDS
    args = ["simulate", "phase_field", "--set", "S=0.3", "--set", "G=1e7",
            *(a for k, v in TINY.items() for a in ("--option", f"{k}={v}"))]
    result = CliRunner().invoke(app, args)
    doc = json.loads(result.stdout)
    assert result.exit_code == 1 and doc["status"] == "nonconverged"
    assert {"lambda", "k_V"} <= set(doc["outputs"])
    # progress on stderr, a line per tenth of the step budget, the last at the budget
    lines = [ln for ln in result.stderr.splitlines() if ln.startswith("phase_field: ")]
    steps = doc["diagnostics"]["steps"]
    assert len(lines) >= 2 and f"{steps}/{steps} steps" in lines[-1], result.stderr


def test_progress_counts_toward_the_earliest_steady_end():
    """The progress fraction follows the simulated time before the earliest steady end
    (min_travel) when that comes before the step budget: here at most 0.95 after the
    first chunk, not the budget's small share; it never falls."""
    p = phase_field.parameters(WORKED)
    seen = []
    opts = PhaseFieldOptions(**{**TINY, "max_steps": 100000}, min_travel=1e-6)
    solver.run(p, opts, progress=lambda done, text: seen.append((done, text)))
    fractions = [f for f, _ in seen]
    assert fractions[0] == pytest.approx(0.95) and fractions == sorted(fractions)
    assert "steady from" in seen[0][1] and all(0 < f <= 1 for f in fractions)


@pytest.mark.slow
def test_cells_at_0_3_m_s_from_the_cli():
    # the "done when": the default run at 0.3 m/s, 1e7 K/m is a steady cell array
    result = CliRunner().invoke(app, ["simulate", "phase_field", "--set", "S=0.3", "--set",
                                      "G=1e7"])
    doc = json.loads(result.stdout)
    assert result.exit_code == 0 and doc["status"] == "ok", doc["message"]
    assert doc["diagnostics"]["cells"] >= 2 and doc["outputs"]["amplitude"] > 0.005
    # trapping as in Aziz's model (variant A) within 5 % at the tip of the cells
    aziz = float(solidification.simulate_batch(**doc["inputs"])["k_V"])
    assert doc["outputs"]["k_V"] == pytest.approx(aziz, rel=0.05)
    assert 0.0 < doc["outputs"]["lambda"] < 1.0


def test_a_modulation_below_one_cell_is_a_flat_front():
    dx, nx = 5e-9, 64
    x = np.arange(nx) / nx
    assert outputs.dominant_mode(0.9 * dx * np.cos(2 * np.pi * 3 * x), dx)[0] == 0
    assert outputs.dominant_mode(1.1 * dx * np.cos(2 * np.pi * 3 * x), dx)[0] == 3


def test_a_domain_narrower_than_two_cells_is_a_failed_run():
    """A 50 nm domain (10 cells of 5 nm) holds one cell of the array: its 'spacing' would
    be the domain's width, so the run fails, saying so, instead of reporting it."""
    res = phase_field.simulate({"S": 0.3, "G": 1e7}, nx=10)
    assert res.status == "failed", res
    assert res.message.startswith("phase_field: the domain (0.05 um across) held 1 cells, "
                                  "so lambda is its width"), res.message


def test_equilibrium_start_is_the_reference_set_up():
    opts = PhaseFieldOptions(nx=4, ny=32, amplitude=0.0, start="equilibrium")
    phi, xs, xl, _ = solver.initial_fields(opts, C, 0.3)
    np.testing.assert_allclose(xl, C.c0)
    np.testing.assert_allclose(xs, C.k_e * C.c0)
    assert phi[0, 0] == 1.0 and phi[-1, 0] == 0.0


# A campaign run of the ninb-pf design (low speed, high interface permeability) whose
# fields diverge within 1 200 steps at the stable step of diffusion and phase field:
# the anti-trapping current there needs a smaller step.
STIFF = {"S": 0.04, "G": 1588979.708, "sigma": 1.2007944e-06, "M": 10.5185,
         "p_int": 29335.3}


def _stable_dt(inputs) -> float:
    p = phase_field.parameters(inputs)
    return model.stable_time_step(p.sigma, p.mobility, PhaseFieldOptions().dx, solver.CONSTANTS)


@pytest.mark.slow
def test_a_diverging_run_starts_again_with_half_the_step():
    # a quarter of the default width diverges the same way (in a quarter of the time)
    res = phase_field.simulate(STIFF, max_steps=1600, nx=96)
    # dt_halvings 1: the run at the stable step diverged, the one at half of it did not
    assert res.status == "nonconverged" and res.diagnostics["dt_halvings"] == 1
    assert res.diagnostics["dt_s"] == pytest.approx(_stable_dt(STIFF) / 2, rel=1e-12)
    assert res.diagnostics["steps"] == 3200  # the same simulated time as the budget
    assert res.diagnostics["simulated_time_s"] == pytest.approx(1600 * _stable_dt(STIFF),
                                                                rel=1e-9)
    assert all(math.isfinite(v) for v in res.outputs.values())


def test_a_stable_run_keeps_its_step():
    res = phase_field.simulate(WORKED, max_steps=400)
    assert res.diagnostics["dt_halvings"] == 0
    assert res.diagnostics["dt_s"] == _stable_dt(WORKED)


def test_a_restart_on_the_same_grid_goes_on_as_one_run():
    """Two runs, the second started from the first's final state, give the fields and
    clock of one run of both budgets: the restart carries the fields, the frame and the
    time."""
    p = phase_field.parameters(WORKED)
    kw = {**TINY, "chunk_cells": 1e-6, "seed": 4}  # chunks of the least 10 steps
    whole = solver.run(p, PhaseFieldOptions(**{**kw, "max_steps": 300}))
    first = solver.run(p, PhaseFieldOptions(**{**kw, "max_steps": 150}))
    second = solver.run(p, PhaseFieldOptions(**{**kw, "max_steps": 150}), restart=first)
    assert second.time == pytest.approx(whole.time, rel=1e-12)
    for name in ("phi", "xs", "xl", "y"):
        np.testing.assert_allclose(second.fields[name], whole.fields[name], rtol=0,
                                   atol=1e-12 * np.abs(whole.fields[name]).max())
    assert second.history[-1].t == pytest.approx(whole.history[-1].t, rel=1e-12)


def test_regrid_interpolates_onto_a_finer_grid_of_the_same_domain():
    """A field linear in y and periodic in x, from 5 nm cells onto 2.5 nm cells: linear
    interpolation between the old centres (periodic across the sides, the nearest row
    beyond the first and last centres); another domain is refused."""
    coarse = PhaseFieldOptions(nx=16, ny=16)
    fine = PhaseFieldOptions(nx=32, ny=32, dx=coarse.dx / 2)
    dx, L = coarse.dx, coarse.nx * coarse.dx
    y = 3e-7 + (np.arange(coarse.ny) + 0.5) * dx
    x = (np.arange(coarse.nx) + 0.5) * dx
    field = (y[:, None] - 3e-7) / (coarse.ny * dx) + 0.0 * x[None, :]
    wave = np.broadcast_to(np.cos(2 * np.pi * x / L)[None, :], field.shape)
    run = {"phi": field, "xs": wave, "xl": 2.0 + wave, "y": y}
    phi, xs, xl, y_off = solver.regrid(run, fine)
    assert y_off == pytest.approx(3e-7, rel=1e-12)
    y_new = y_off + (np.arange(fine.ny) + 0.5) * fine.dx
    expect = (np.clip(y_new, y[0], y[-1]) - 3e-7) / (coarse.ny * dx)
    np.testing.assert_allclose(phi, np.broadcast_to(expect[:, None], phi.shape), atol=1e-12)
    # the first and last fine rows lie beyond the old centres: the nearest row's values
    assert phi[0, 0] == pytest.approx(1 / 32) and phi[-1, 0] == pytest.approx(1 - 1 / 32)
    x_new = (np.arange(fine.nx) + 0.5) * fine.dx
    lin = np.interp(x_new, np.r_[x[-1] - L, x, x[0] + L],
                    np.cos(2 * np.pi * np.r_[x[-1] - L, x, x[0] + L] / L))
    np.testing.assert_allclose(xs, np.broadcast_to(lin, xs.shape), atol=1e-12)
    np.testing.assert_allclose(xl, 2.0 + xs, atol=1e-12)
    with pytest.raises(ValueError, match="domain width"):
        solver.regrid(run, PhaseFieldOptions(nx=30, ny=32, dx=coarse.dx / 2))
