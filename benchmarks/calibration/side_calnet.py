"""calnet side: build_logdensity + sample_nuts (BlackJAX NUTS, chains over 4 host devices).

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


def build(P):
    from calnet.calibration import Beta, build_logdensity, fixed_input_gp

    # surrogate mean = mu0 + k32([x, theta], Xtr; ls) @ c, x-part of the distances once
    mean_fn, args = fixed_input_gp(P["xo"], P["Xtr"], P["ls"], P["c"], P["mu0"])
    return build_logdensity(mean_fn, P["yo"], P["xo"], theta_priors=[Beta(0.0, 1.0)] * 7,
                            mean_args=args, name="koh_anchor",
                            theta_names=[f"t{i}" for i in range(7)], x_names=["x1", "x2"])


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
        rec = dict(side="calnet" + ("-dense" if DENSE else ""), rep=REP, run=run,
                   t_total=t_total, t_compile=a["compile_time"], t_sample=a["sampling_time"],
                   cpu_s=cm.cpu_s, chain_method=a["chain_method"],
                   logp_error=abs(lp - REF_LOGP),
                   mean_n_steps=float(idata.sample_stats["n_steps"].mean()),
                   **diagnostics(idata))
        emit(rec)


if __name__ == "__main__":
    main()
