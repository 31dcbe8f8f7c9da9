"""The surrogate check's runs-needed estimate against what those runs achieve.

For GPs of fixed hyperparameters on Halton designs in 2, 4 and 6 inputs (some inactive:
long length scales), :func:`calnet.calibration.guard.variance_rate` measures the rate of
the GP's variance with its runs from ``n0`` runs, :func:`~calnet.calibration.guard.runs_for`
names the runs that divide the variance by ``F``, and the same GP conditioned on that many
runs gives the factor actually achieved (mean latent variance at 400 random points of the
box). The worst-case count ``n0 F^(d/3)`` (Matern 3/2's rate in d inputs) is beside it.

    PYTHONPATH=src python benchmarks/calibration/runs_needed.py
"""

import jax.numpy as jnp
import numpy as np
from scipy.stats import qmc

from calnet.calibration.guard import runs_for, variance_rate
from calnet.surrogates.gp import condition


def latent_var(gp, points):
    return float(np.mean(np.asarray(gp.predict(jnp.asarray(points))[1])) / float(gp.y_std) ** 2)


def main():
    print("| d | length scales | n0 | F | rate | runs named | worst-case runs | achieved |")
    print("|---|---|---|---|---|---|---|---|")
    for d, ell in ((2, [0.3, 0.5]), (4, [0.3, 0.5, 5.0, 5.0]), (6, [0.4] * 3 + [3.0] * 3)):
        def gp_on(n, d=d, ell=ell):
            x = qmc.Halton(d, seed=3).random(n)
            y = np.sin(3 * x[:, 0]) + x[:, 1] ** 2
            return condition(x, y, lower=np.zeros(d), upper=np.ones(d),
                             lengthscales=np.array(ell), signal_var=1.0, nugget=1e-6)

        points = np.random.default_rng(0).uniform(size=(400, d))
        for n0 in (64, 128):
            for factor in (4.0, 8.0):
                gp = gp_on(n0)
                rate = variance_rate(gp)
                n1 = runs_for(n0, factor, rate)
                got = (f"{latent_var(gp, points) / latent_var(gp_on(n1), points):.2f}"
                       if n1 <= 4000 else "(over 4000 runs: not run)")
                print(f"| {d} | {ell} | {n0} | {factor:g} | {rate:.2f} | {n1} | "
                      f"{int(n0 * factor ** (d / 3))} | {got} |")


if __name__ == "__main__":
    main()
