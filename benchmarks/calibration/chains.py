"""How NUTS chains should share a small CPU: sequential, parallel (pmap over XLA host
devices) or vectorized (vmap on one device), on two log-densities:

* ``anchor``: the koh_anchor problem (7 theta, 30 points, GP mean only; 50 us per
  value-and-gradient);
* ``ninb``: the ninb thermal stage as ``calnet run`` builds it (7 theta, 30 widths, GP
  mean and emulator variance of a 208-run surrogate in 9-D; about 0.6 ms per gradient).

Each (problem, method) runs in a fresh process; 4 chains x (1000 warm-up + 1000 draws).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/calibration/chains.py

The ninb problem needs fitted surrogates: ``calnet run examples/ninb --out out/ninb``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def child(problem: str, method: str, devices: int) -> None:
    from calnet.calibration.devices import configure_host_devices

    configure_host_devices(devices)
    import jax

    assert len(jax.devices()) == devices  # backend started: later requests cannot change it
    import arviz as az
    import numpy as np

    from calnet.calibration import sample_nuts

    if problem == "anchor":
        sys.path.insert(0, str(HERE))
        from common import load_problem

        argv, sys.argv = sys.argv, sys.argv[:1]  # side_calnet reads its own argv at import
        from side_calnet import build
        sys.argv = argv

        ld = build(load_problem())
    else:
        from calnet.calibration.calibrate_network import build_koh
        from calnet.calibration.terms import parameter_keys
        from calnet.spec import load_spec, read_all
        from calnet.surrogates.fit_network import Surrogates

        net = load_spec(ROOT / "examples" / "ninb")
        sur = Surrogates.load(ROOT / "out" / "ninb" / "surrogates")
        width = read_all(net)["width"].train
        ld = build_koh(net, sur, free=parameter_keys(net, "melt_pool"),
                       datasets={"width": width}, name="ninb thermal")
    t0 = time.perf_counter()
    idata = sample_nuts(ld, seed=1, num_chains=4, num_warmup=1000, num_draws=1000,
                        chain_method=method)
    wall = time.perf_counter() - t0
    ess = az.ess(idata.posterior, method="bulk")
    min_ess = float(min(np.min(ess[v].values) for v in ess.data_vars))
    a = idata.posterior.attrs
    print(json.dumps({"problem": problem, "method": method, "devices": devices,
                      "compile_s": round(float(a["compile_time"]), 2),
                      "sampling_s": round(float(a["sampling_time"]), 2),
                      "wall_s": round(wall, 2), "min_ess_bulk": round(min_ess),
                      "ess_per_s": round(min_ess / float(a["sampling_time"]))}))


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "child":
        child(sys.argv[2], sys.argv[3], int(sys.argv[4]))
        return
    cases = [(p, m, d) for p in ("anchor", "ninb")
             for m, d in (("sequential", 1), ("vectorized", 1), ("parallel", 2),
                          ("parallel", 4))]
    env = {**os.environ, "CALNET_JAX_CACHE": "off"}
    for p, m, d in cases:
        out = subprocess.run([sys.executable, __file__, "child", p, m, str(d)], env=env,
                             capture_output=True, text=True, check=True)
        print(out.stdout.strip().splitlines()[-1], flush=True)


if __name__ == "__main__":
    main()
