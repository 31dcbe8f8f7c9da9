"""Cost of the case study's surrogate fits with their k-fold cross-validation, cold.

One process per call: fits every surrogate of examples/ninb with its cross-validation
(``fit_surrogates(cv=True)``) on a cold compilation cache, and prints one JSON line: the
wall time of the fits, the process's CPU time, the number of XLA programs compiled and
the seconds spent compiling them, and each output's CV RMSE. Compare two commits
interleaved on one idle machine (repository root)::

    git worktree add --detach /tmp/calnet_base BASE
    for i in 1 2; do for src in /tmp/calnet_base/src src; do
        CALNET_JAX_CACHE=off PYTHONPATH=$src python benchmarks/surrogates/cv_programs.py
    done; done
"""

from __future__ import annotations

import json
import logging
import re
import resource
import time
from pathlib import Path

import jax

import calnet
from calnet.spec import load_spec
from calnet.surrogates.fit_network import fit_surrogates

SPEC = Path(__file__).resolve().parents[2] / "examples" / "ninb" / "network.yaml"


class _Compiles(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.count, self.seconds = 0, 0.0

    def emit(self, record):
        m = re.search(r"Finished XLA compilation of .* in ([\d.e-]+) sec", record.getMessage())
        if m:
            self.count += 1
            self.seconds += float(m.group(1))


def main() -> None:
    compiles = _Compiles()
    logging.getLogger("jax").addHandler(compiles)
    logging.getLogger("jax").setLevel(logging.DEBUG)
    jax.config.update("jax_log_compiles", True)
    network = load_spec(SPEC)
    t0 = time.perf_counter()
    surrogates = fit_surrogates(network, cv=True)
    wall = time.perf_counter() - t0
    use = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"calnet": str(Path(calnet.__file__).parent), "wall_s": round(wall, 1),
                      "process_cpu_s": round(use.ru_utime + use.ru_stime, 1),
                      "programs": compiles.count, "compile_s": round(compiles.seconds, 1),
                      "cv_rmse": {k: float(f"{s.cv.rmse:.6g}")
                                  for k, s in surrogates.items.items()}}))


if __name__ == "__main__":
    main()
