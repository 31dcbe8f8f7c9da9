"""PyMC side (run with benchmarks/.venv-peers/bin/python; PyMC is not a calnet dependency).

usage: python side_pymc.py REP default|numba
Same model as calnet's (koh_anchor: Beta(1.1,1.1) theta, LogNormal(0, 0.5) length scales,
InverseGamma(2, 1) variances, MVN likelihood with the discrepancy integrated out), written
with the same precomputation: the x-part of the surrogate's kernel distances is a constant.
PyMC's NUTS, 4 chains on cores=2 (PyMC's default on this 2-core machine).
"""

import sys
import time

T0 = time.perf_counter()
import pymc as pm  # noqa: E402
import pytensor  # noqa: E402
import pytensor.tensor as pt  # noqa: E402
from common import (  # noqa: E402
    EPS_R2,
    NCHAINS,
    NDRAW,
    NWARM,
    REF_LOGP,
    U_TEST,
    CpuMeter,
    diagnostics,
    emit,
    load_problem,
    log,
)

T_IMPORT = time.perf_counter() - T0
REP = int(sys.argv[1]) if len(sys.argv) > 1 else 0
VARIANT = sys.argv[2] if len(sys.argv) > 2 else "default"


def build(P):
    xo, yo, ls, Xtr = P["xo"], P["yo"], P["ls"], P["Xtr"]
    n = len(yo)
    d2x_tr = (((xo[:, None, :] - Xtr[None, :, :2]) / ls[:2]) ** 2).sum(-1)  # (n, N) const
    t_tr = Xtr[:, 2:] / ls[2:]
    d2x = (xo[:, None, :] - xo[None, :, :]) ** 2
    with pm.Model() as model:
        theta = pm.Beta("theta", 1.1, 1.1, shape=7)
        ell = pm.LogNormal("ell", 0.0, 0.5, shape=2)
        sd2 = pm.InverseGamma("sd2", 2.0, 1.0)
        se2 = pm.InverseGamma("se2", 2.0, 1.0)
        d2t = pt.sum((theta / ls[2:] - t_tr) ** 2, axis=-1)  # (N,)
        r = pt.sqrt(3.0 * (d2x_tr + d2t[None, :] + EPS_R2))
        mean = P["mu0"] + pt.dot((1.0 + r) * pt.exp(-r), P["c"])
        K = sd2 * pt.exp(-0.5 * pt.sum(d2x / ell**2, axis=-1)) + se2 * pt.eye(n)
        pm.MvNormal("y", mu=mean, cov=K, observed=yo)
    return model


def main():
    P = load_problem()
    model = build(P)
    lpf = model.compile_logp()
    lp = float(lpf({"theta_logodds__": U_TEST[:7], "ell_log__": U_TEST[7:9],
                    "sd2_log__": U_TEST[9], "se2_log__": U_TEST[10]}))
    log(f"[pymc {VARIANT}] import {T_IMPORT:.1f}s mode={pytensor.config.mode} "
        f"logp={lp:.6f} ref={REF_LOGP}")
    kw = dict(draws=NDRAW, tune=NWARM, chains=NCHAINS, cores=2, progressbar=False,
              compute_convergence_checks=False, random_seed=1000 * REP + 1)
    if VARIANT == "numba":
        kw["compile_kwargs"] = dict(mode="NUMBA")
    with CpuMeter() as cm, model:
        t0 = time.perf_counter()
        idata = pm.sample(**kw)
        t_total = time.perf_counter() - t0
    t_sample = float(idata.posterior.attrs.get("sampling_time",
                                               idata.sample_stats.attrs.get("sampling_time")))
    emit(dict(side=f"pymc-{VARIANT}", rep=REP, run=1, t_total=t_total,
              t_compile=t_total - t_sample, t_sample=t_sample, cpu_s=cm.cpu_s,
              logp_error=abs(lp - REF_LOGP),
              mean_n_steps=float(idata.sample_stats["n_steps"].mean()),
              **diagnostics(idata)))


if __name__ == "__main__":
    main()
