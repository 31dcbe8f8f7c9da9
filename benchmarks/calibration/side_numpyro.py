"""NumPyro side, for calnet's choice of sampler: NumPyro's NUTS on calnet's own
log-density (potential_fn = -logdensity), chain_method="parallel" over 4 host devices.

usage: python side_numpyro.py REP   (run 2 re-runs the same MCMC object: NumPyro recompiles)
"""

import sys
import time

from calnet.calibration.devices import configure_host_devices

DEV = configure_host_devices(4)

import numpy as np  # noqa: E402
from common import NCHAINS, NDRAW, NWARM, CpuMeter, diagnostics, emit, load_problem  # noqa: E402
from side_calnet import build  # noqa: E402

REP = int(sys.argv[1]) if len(sys.argv) > 1 else 0


COMPILE_S = [0.0]


def _on_event(event, duration, **kw):
    if event.startswith("/jax/core/compile/") and event.endswith("_duration"):
        COMPILE_S[0] += duration


def main():
    import arviz as az
    import jax
    from numpyro.infer import MCMC, NUTS

    jax.monitoring.register_event_duration_secs_listener(_on_event)

    P = load_problem()
    ld = build(P)
    mcmc = MCMC(NUTS(potential_fn=lambda u: -ld.logdensity(u)), num_warmup=NWARM,
                num_samples=NDRAW, num_chains=NCHAINS, chain_method="parallel",
                progress_bar=False)
    for run in (1, 2):
        seed = 1000 * REP + run
        init = jax.numpy.asarray(ld.init(seed, NCHAINS))
        c0 = COMPILE_S[0]
        with CpuMeter() as cm:
            t0 = time.perf_counter()
            mcmc.run(jax.random.PRNGKey(seed), init_params=init,
                     extra_fields=("diverging", "num_steps"))
            u = np.asarray(jax.block_until_ready(mcmc.get_samples(group_by_chain=True)))
            t_total = time.perf_counter() - t0
        c = jax.vmap(jax.vmap(ld.constrain))(u)
        extra = mcmc.get_extra_fields(group_by_chain=True)
        idata = az.from_dict(posterior={k: np.asarray(v) for k, v in c.items()},
                             sample_stats={"diverging": np.asarray(extra["diverging"])})
        # compile time is only known from jax's compile events, which overlap across the
        # pmap'ed chains: reported for information, the comparison uses t_total
        emit(dict(side="numpyro", rep=REP, run=run, t_total=t_total,
                  t_compile=COMPILE_S[0] - c0, t_sample=None, cpu_s=cm.cpu_s,
                  mean_n_steps=float(np.asarray(extra["num_steps"]).mean()),
                  **diagnostics(idata, names=("theta_m", "ell_obs", "sd2_obs", "se2_obs"))))


if __name__ == "__main__":
    main()
