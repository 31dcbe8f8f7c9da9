"""Cost of one value-and-gradient of the case study's joint log-density, by discrepancy.

The density of ``calnet run examples/ninb`` (both data sets, joint, emulator variance),
built from a run folder's surrogates, with each data set's noise and discrepancy as the
spec has them (``spec``: the reference KOH), or with calnet's defaults: half-normal
priors and a discrepancy ``non_orthogonal``, ``orthogonal_own`` (orthogonal to the
observed model's own parameters only) or ``orthogonal`` (calnet's default: also to the
parameters upstream). Each variant in a fresh process, 500 value-and-gradients in one
``lax.scan`` after a warm-up call, one thread; prints one JSON line per variant.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/calibration/gradient.py out/ninb
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
VARIANTS = ("spec", "non_orthogonal", "orthogonal_own", "orthogonal")


def child(run: str, variant: str) -> None:
    import jax

    import calnet.calibration.calibrate_network as cn
    from calnet.calibration.terms import parameter_keys
    from calnet.spec import load_spec, read_all
    from calnet.spec.models import DiscrepancySettings, NoiseSettings
    from calnet.surrogates.fit_network import Surrogates

    net = load_spec(ROOT / "examples" / "ninb")
    if variant != "spec":
        data = [d.model_copy(update={"noise": NoiseSettings(), "discrepancy":
                                     DiscrepancySettings(orthogonal=variant != "non_orthogonal")})
                for d in net.data]
        net = net.model_copy(update={"data": data})
    if variant == "orthogonal_own":
        make = cn.make_term
        cn.make_term = lambda *a, **k: make(*a, **{**k, "directions": ()})
    sur = Surrogates.load(Path(run) / "surrogates")
    datasets = {k: v.train for k, v in read_all(net).items()}
    free = [k for m in net.order for k in parameter_keys(net, m)]
    ld = cn.build_koh(net, sur, free=free, datasets=datasets, name="ninb")

    def body(u, _):
        value, grad = jax.value_and_grad(lambda v: ld.spec.logdensity(ld.data, v))(u)
        return u + 1e-6 * grad, value

    n = 500
    run_scan = jax.jit(lambda u: jax.lax.scan(body, u, None, length=n))
    u0 = jax.numpy.full(ld.dim, 0.01)
    t0 = time.perf_counter()
    run_scan(u0)[0].block_until_ready()
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    run_scan(u0)[0].block_until_ready()
    per = (time.perf_counter() - t0) / n
    print(json.dumps({"variant": variant, "ms_per_gradient": round(per * 1e3, 3),
                      "compile_and_first_s": round(first, 1), "dim": ld.dim}))


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "child":
        child(sys.argv[2], sys.argv[3])
        return
    run = sys.argv[1] if len(sys.argv) > 1 else "out/ninb"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "CALNET_JAX_CACHE": "off",
           "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false"}
    for variant in VARIANTS:
        out = subprocess.run([sys.executable, __file__, "child", run, variant], env=env,
                             capture_output=True, text=True, check=True)
        print(out.stdout.strip().splitlines()[-1], flush=True)


if __name__ == "__main__":
    main()
