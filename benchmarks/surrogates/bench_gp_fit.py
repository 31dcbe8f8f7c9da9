"""GP surrogate fit: calnet vs scikit-learn on the same problem, bounds and restarts.

Problem: the koh_anchor simulator ``f_sim`` (2 control inputs + 7 parameters, all in
[0, 1]), training sets of 240 and 1000 Latin-hypercube points in 9-D, 500 held-out LHS
points. Both libraries fit Matern 3/2 ARD + nugget with standardised outputs, the same
hyperparameter bounds and a default start plus 5 random restarts. Each fit's quality is
scored with calnet's own negative log marginal likelihood (standardised outputs, unit
cube) at that fit's hyperparameters, so the numbers are on one scale.

Run with single-threaded BLAS for both libraries (threaded BLAS on a shared box makes
the timings depend on the load, not on the code)::

    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 \
        python benchmarks/surrogates/bench_gp_fit.py --sizes 240 1000

Prints one JSON line per (library, size) and a Markdown table at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

N_TEST, N_RESTARTS = 500, 5


def f_sim(z: np.ndarray) -> np.ndarray:
    """koh_anchor ``f_sim``: z (n, 9) = [x (2), theta (7)] in [0, 1]^9 -> (n,)."""
    x, t = z[:, :2], z[:, 2:]
    return (np.sin(3 * x[:, 0]) + x[:, 1] * t[:, 0] + 0.5 * t[:, 1] ** 2
            + 0.3 * x[:, 0] * t[:, 2] + 0.2 * t[:, 3:7].sum(1) * x[:, 1])


def lhs(n: int, d: int, seed: int) -> np.ndarray:
    from scipy.stats import qmc

    return qmc.LatinHypercube(d=d, seed=seed).random(n)


def score(log_params, z, y, zte, yte):
    """calnet NLML at ``log_params`` = [log ell (9), log s2, log nugget], and test RMSE."""
    import jax.numpy as jnp

    from calnet.surrogates import condition, neg_log_marginal_likelihood

    ys = (y - y.mean()) / y.std()
    nlml = float(neg_log_marginal_likelihood(jnp.asarray(log_params), z, ys))
    p = np.exp(log_params)
    gp = condition(z, y, lower=np.zeros(9), upper=np.ones(9), lengthscales=p[:-2],
                   signal_var=p[-2], nugget=p[-1])
    rmse = float(np.sqrt(np.mean((np.asarray(gp.predict(zte)[0]) - yte) ** 2)))
    return nlml, rmse


def run_calnet(z, y):
    from calnet.surrogates import fit_gp

    out = {}
    for label in ("cold", "warm"):  # cold includes JIT compilation for this data size
        t0 = time.perf_counter()
        gp = fit_gp(z, y, lower=np.zeros(9), upper=np.ones(9), n_restarts=N_RESTARTS, seed=0)
        out[f"time_{label}_s"] = time.perf_counter() - t0
    return out, np.asarray(gp.log_params)


def run_sklearn(z, y):
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    from calnet.surrogates.fit import LENGTHSCALE_BOUNDS, NUGGET_BOUNDS, SIGNAL_VAR_BOUNDS

    kernel = (ConstantKernel(1.0, SIGNAL_VAR_BOUNDS)
              * Matern(np.full(9, 0.5), LENGTHSCALE_BOUNDS, nu=1.5)
              + WhiteKernel(1e-6, NUGGET_BOUNDS))
    t0 = time.perf_counter()
    gp = GaussianProcessRegressor(kernel, normalize_y=True, n_restarts_optimizer=N_RESTARTS,
                                  random_state=0).fit(z, y)
    elapsed = time.perf_counter() - t0
    k = gp.kernel_
    log_params = np.log(np.r_[k.k1.k2.length_scale, k.k1.k1.constant_value, k.k2.noise_level])
    return {"time_s": elapsed}, log_params


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[240, 1000])
    ap.add_argument("--out", default=None, help="append JSON lines to this file")
    args = ap.parse_args()
    zte = lhs(N_TEST, 9, seed=4)
    yte = f_sim(zte)
    rows = []
    for n in args.sizes:
        z = lhs(n, 9, seed=1)
        y = f_sim(z)
        for lib, runner in (("calnet", run_calnet), ("scikit-learn", run_sklearn)):
            timing, log_params = runner(z, y)
            nlml, rmse = score(log_params, z, y, zte, yte)
            row = {"library": lib, "n": n, **timing, "nlml": nlml, "rmse_test": rmse,
                   "nugget": float(np.exp(log_params[-1])), "loadavg": os.getloadavg()[0],
                   "threads": os.environ.get("OPENBLAS_NUM_THREADS")}
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.out:
                with open(args.out, "a") as fh:
                    fh.write(json.dumps(row) + "\n")
    print("\n| n | library | fit wall time (s) | NLML (calnet scale) | held-out RMSE |")
    print("|---|---|---|---|---|")
    for r in rows:
        t = (f"{r['time_warm_s']:.1f} (cold, incl. JIT: {r['time_cold_s']:.1f})"
             if "time_warm_s" in r else f"{r['time_s']:.1f}")
        print(f"| {r['n']} | {r['library']} | {t} | {r['nlml']:.3f} | {r['rmse_test']:.2e} |")


if __name__ == "__main__":
    main()
