"""The GP's mean function: constant, linear and quadratic, and what ``mean="auto"`` picks.

Part 1, functions with known structure on the unit cube scaled to a box (uniform random
training runs, 2000 held-out points): held-out RMSE, the mean predicted sd, their ratio
(1 is honest; above 1 overstates the error), the mean squared standardised error
``mean(err^2 / var)`` (1 is honest) and the closed-form leave-one-out log density that
``auto`` compares (it tries a trend with at least 5 runs per coefficient). Part 2, the
case study's three surrogates (examples/ninb, shipped stores): k-fold cross-validation
of each mean function, as ``calnet surrogates`` runs it.

Usage (repository root)::

    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 python benchmarks/surrogates/mean_function.py
"""

from __future__ import annotations

import numpy as np

from calnet.errors import SurrogateError
from calnet.spec import load_spec
from calnet.surrogates import cross_validate, fit_gp
from calnet.surrogates.fit import loo_log_density
from calnet.surrogates.fit_network import _jobs


def _functions(d: int):
    w = np.linspace(1.0, -0.5, d)

    def linear(u):
        return 2.0 + u @ w

    def trend_and_bump(u):
        return 2.0 + u @ w + 0.3 * np.sin(3.0 * u[:, 0])

    def interaction(u):  # a parameter that scales a control input
        return 1.0 + u[:, 1] * u[:, 0] + 0.2 * u[:, 0] ** 2

    def wiggly(u):
        return np.sin(6.0 * u[:, 0]) + np.cos(4.0 * u[:, 1]) * u[:, -1]

    return {"linear": linear, "trend + bump": trend_and_bump, "interaction": interaction,
            "wiggly": wiggly}


def part1() -> None:
    print("| function | d | n | mean | held-out RMSE | mean sd | sd / RMSE | mean z^2 "
          "| LOO log density | auto |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for d, n in ((3, 50), (6, 60)):
        rng = np.random.default_rng(d)
        lo, hi = np.zeros(d), np.arange(1.0, d + 1.0)
        u, ut = rng.random((n, d)), rng.random((2000, d))
        x, xt = lo + u * (hi - lo), lo + ut * (hi - lo)
        for name, f in _functions(d).items():
            y, yt = f(u), f(ut)
            auto = fit_gp(x, y, lower=lo, upper=hi, mean="auto", n_restarts=3).mean
            for mean in ("constant", "linear", "quadratic"):
                try:
                    gp = fit_gp(x, y, lower=lo, upper=hi, mean=mean, n_restarts=3)
                except SurrogateError:  # more coefficients than the runs allow
                    continue
                m, v = (np.asarray(a) for a in gp.predict(xt))
                err = m - yt
                rmse, sd = float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(v)))
                print(f"| {name} | {d} | {n} | {mean} | {rmse:.2e} | {sd:.2e} | "
                      f"{sd / rmse:.3g} | {np.mean(err**2 / v):.3g} | "
                      f"{loo_log_density(gp):.1f} | {'yes' if auto == mean else ''} |")


def part2() -> None:
    net = load_spec("examples/ninb")
    print("\n| output | mean | k | CV MAPE | CV RMSE | 95 % coverage | mean z^2 "
          "| LOO log density | auto |")
    print("|---|---|---|---|---|---|---|---|---|")
    for job in _jobs(net, None, net.settings.seed, None, None):
        fits = {m: fit_gp(job.x, job.y, **{**job.kw, "mean": m})
                for m in ("constant", "linear", "quadratic")}
        auto = fit_gp(job.x, job.y, **{**job.kw, "mean": "auto"}).mean
        scores = {m: loo_log_density(gp) for m, gp in fits.items()}
        for mean, gp in fits.items():
            cv = cross_validate(job.x, job.y, k=job.folds,
                                **{**job.kw, "n_restarts": 0, "mean": mean},
                                init=np.asarray(gp.log_params))
            z = ((np.log(cv.y) if cv.transform == "log" else cv.y) - cv.mean_modelled) ** 2
            z2 = float(np.mean(z / cv.var_modelled))
            print(f"| {job.kw['name']} | {mean} | {cv.k} | {cv.mape:.1f} % | {cv.rmse:.3g} | "
                  f"{cv.coverage95:.2f} | {z2:.2f} | {scores[mean]:.1f} | "
                  f"{'yes' if mean == auto else ''} |")


if __name__ == "__main__":
    part1()
    part2()
