"""calnet side: the shipped KOH model (build_koh) + sample_nuts (BlackJAX NUTS, chains
over 4 host devices).

usage: python side_calnet.py REP   (run 1: compile + sample; run 2: cached sampler, new seed)
"""

import sys
import time

from calnet.calibration.devices import configure_host_devices

DEV = configure_host_devices(4)  # before jax is imported

import numpy as np  # noqa: E402
from common import (  # noqa: E402
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

REP = int(sys.argv[1]) if len(sys.argv) > 1 else 0
DENSE = len(sys.argv) > 2 and sys.argv[2] == "dense"



ANCHOR_SPEC = """
models:
  m:
    simulator: python:nowhere:f
    inputs: {x1: {lower: 0, upper: 1}, x2: {lower: 0, upper: 1}}
    parameters: {PARAMS}
    outputs: {y: {measurable: true}}
data:
  obs:
    path: obs.csv
    observes: m.y
    columns: {x1: x1, x2: x2, y: y}
    noise: {prior: {dist: invgamma, a: 2, b: 1}}
    discrepancy: {sd_prior: {dist: invgamma, a: 2, b: 1}, orthogonal: false}
settings:
  calibration: {emulator_variance: false}
""".replace("PARAMS", ", ".join(f"t{i}: {{lower: 0, upper: 1}}" for i in range(7)))


def build(P):
    """The koh_anchor problem as a one-model calnet network (the shipped KOH model)."""
    import tempfile
    from pathlib import Path

    import jax.numpy as jnp

    from calnet.calibration.calibrate_network import build_koh
    from calnet.spec import load_spec, read_all
    from calnet.surrogates.fit_network import OutputSurrogate, Surrogates
    from calnet.surrogates.gp import FittedGP, constant_mean

    folder = Path(tempfile.mkdtemp())
    (folder / "network.yaml").write_text(ANCHOR_SPEC)
    (folder / "obs.csv").write_text("x1,x2,y\n" + "".join(
        f"{a},{b},{c}\n" for (a, b), c in zip(P["xo"], P["yo"], strict=True)))
    network = load_spec(folder)
    amp = float(P["amp"])
    # surrogate mean = mu0 + k32([x, theta], Xtr; ls) @ c as a FittedGP (variance unused)
    gp = FittedGP(x_train=jnp.asarray(P["Xtr"]), alpha=jnp.asarray(P["c"] / amp),
                  chol=jnp.eye(len(P["Xtr"])), lengthscales=jnp.asarray(P["ls"]),
                  signal_var=jnp.asarray(amp), nugget=jnp.asarray(P["noise"]),
                  lower=jnp.zeros(9), upper=jnp.ones(9), y_mean=jnp.asarray(P["mu0"]),
                  y_std=jnp.asarray(1.0), nlml=jnp.asarray(float("nan")), name="y",
                  **constant_mean(len(P["Xtr"])))
    sur = Surrogates({"m.y": OutputSurrogate("m", "y", gp, None, 240, 0)})
    data = {k: v.train for k, v in read_all(network).items()}
    return build_koh(network, sur, free=[f"m.t{i}" for i in range(7)], datasets=data,
                     emulator_variance=False, name="koh_anchor")


def main():
    t0 = time.perf_counter()
    import arviz  # noqa: F401  (imported before timing, as PyMC imports it at import time)
    import jax

    from calnet.calibration import sample_nuts
    log(f"[calnet] {DEV.message}; devices={jax.local_device_count()} "
        f"import {time.perf_counter() - t0:.1f}s")
    P = load_problem()
    for run in (1, 2):
        with CpuMeter() as cm:
            t0 = time.perf_counter()
            ld = build(P)
            idata = sample_nuts(ld, seed=1000 * REP + run, num_chains=NCHAINS,
                                num_warmup=NWARM, num_draws=NDRAW, dense_mass=DENSE)
            t_total = time.perf_counter() - t0
        lp = float(ld.logdensity(np.asarray(U_TEST)))
        a = idata.posterior.attrs
        side = "calnet" + ("-dense" if DENSE else "")
        rec = dict(side=side, rep=REP, run=run,
                   t_total=t_total, t_compile=a["compile_time"], t_sample=a["sampling_time"],
                   cpu_s=cm.cpu_s, chain_method=a["chain_method"],
                   logp_error=abs(lp - REF_LOGP),
                   mean_n_steps=float(idata.sample_stats["n_steps"].mean()),
                   **diagnostics(idata, names=("theta_m", "ell_obs", "sd2_obs", "se2_obs")))
        emit(rec)


if __name__ == "__main__":
    main()
