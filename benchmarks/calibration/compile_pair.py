"""Do two sampler compilations run side by side? The case study's sampler and its
no_discrepancy variant's, compiled one after the other (``seq``) or in two threads
(``threads``), in one process; prints each one's lowering and compile seconds and the
process's wall and CPU seconds.

Usage (repository root, after ``calnet run examples/ninb --out OUT``):

    .venv/bin/python benchmarks/calibration/compile_pair.py OUT seq
    .venv/bin/python benchmarks/calibration/compile_pair.py OUT threads
"""

from __future__ import annotations

import sys
import threading
import time

from calnet.calibration.devices import configure_host_devices

configure_host_devices(2)

import jax  # noqa: E402
import numpy as np  # noqa: E402

import calnet.calibration.sampling as sampling  # noqa: E402
from calnet.calibration.calibrate_network import _all_keys, build_koh  # noqa: E402
from calnet.spec import load_spec, read_all  # noqa: E402
from calnet.surrogates.fit_network import Surrogates  # noqa: E402
from calnet.validation import variant  # noqa: E402


def compile_one(ld, chains: int, warmup: int, draws: int, out: dict, name: str) -> None:
    cfg = sampling._Config(ld.spec, ld.dim, warmup, draws, 1, 0.8, 10, False, "parallel", 2, 0)

    def host(a):
        return a.reshape((2, chains // 2) + a.shape[1:])

    keys = np.asarray(jax.random.split(jax.random.PRNGKey(0), chains))
    t0 = time.perf_counter()
    lowered = sampling._build(cfg).lower(host(keys), host(np.asarray(ld.init(0, chains))),
                                         host(np.arange(chains)), ld.data)
    t1 = time.perf_counter()
    lowered.compile()
    out[name] = (round(t1 - t0, 2), round(time.perf_counter() - t1, 2))


def main(run_dir: str, how: str) -> None:
    network = load_spec("examples/ninb")
    sur = Surrogates.load(f"{run_dir}/surrogates")
    spec = build_koh(network, sur, free=_all_keys(network), datasets=read_all(network),
                     name="joint")
    other = variant(network, "no_discrepancy")
    var = build_koh(other, sur, free=_all_keys(other), datasets=read_all(other), name="joint")
    jobs = [(spec, 4, 500, 500, "spec"), (var, 2, 300, 500, "no_discrepancy")]
    out: dict = {}
    c0, t0 = time.process_time(), time.perf_counter()
    if how == "seq":
        for job in jobs:
            compile_one(*job[:4], out, job[4])
    else:
        threads = [threading.Thread(target=compile_one, args=(*job[:4], out, job[4]))
                   for job in jobs]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    print(how, "(lowering s, compile s):", out,
          f"wall {time.perf_counter() - t0:.2f} s, CPU {time.process_time() - c0:.2f} s")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
