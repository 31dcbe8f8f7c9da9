"""Shared pieces of the KOH sampler benchmark (no jax/pymc imports: used by both venvs).

The problem is the koh_anchor one (7 theta, SE discrepancy over 2 control inputs, 30
observations, Matern-3/2 GP surrogate on 240 runs); its data live in
tests/calibration/data/koh_anchor.npz.
"""

import json
import os
import sys
import threading
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PROBLEM_FILE = os.path.join(ROOT, "tests", "calibration", "data", "koh_anchor.npz")
U_TEST = np.array([0.1, -0.3, 0.5, -1.0, 0.2, 0.7, 0.0, -0.2, 0.3, -1.5, -2.0])
REF_LOGP = -16.747614  # NumPy/scipy reference of the unconstrained log-density at U_TEST
EPS_R2 = 1e-12
NCHAINS = int(os.environ.get("KOH_NCHAINS", 4))
NWARM = int(os.environ.get("KOH_NWARM", 1000))
NDRAW = int(os.environ.get("KOH_NDRAW", 1000))


def load_problem():
    d = np.load(PROBLEM_FILE)
    return {k: d[k] for k in d.files}


def diagnostics(idata, names=("theta", "ell", "sd2", "se2")):
    """min bulk ESS and max R-hat over all 11 scalar parameters, divergences, means."""
    import arviz as az

    post = idata.posterior[list(names)]
    ess, rhat = az.ess(post, method="bulk"), az.rhat(post)
    ess_all = np.concatenate([np.ravel(ess[v].values) for v in names])
    rhat_all = np.concatenate([np.ravel(rhat[v].values) for v in names])
    theta = post[names[0]].values
    return {"min_ess_bulk": float(ess_all.min()), "max_rhat": float(rhat_all.max()),
            "divergences": int(np.asarray(idata.sample_stats["diverging"]).sum()),
            "theta_mean": np.round(theta.reshape(-1, theta.shape[-1]).mean(0), 4).tolist()}


class CpuMeter:
    """CPU seconds of every process whose cwd is ``cwd`` (this one and its workers,
    PyMC's forkserver children included), sampled from /proc; the box is shared, so CPU
    seconds are reported beside wall time."""

    def __init__(self, cwd=None, period=0.2):
        self.cwd, self.period = os.path.realpath(cwd or os.getcwd()), period

    def _scan(self):
        tck, out = os.sysconf("SC_CLK_TCK"), {}
        for pid in os.listdir("/proc"):
            if not pid.isdigit():
                continue
            try:
                if os.path.realpath(os.readlink(f"/proc/{pid}/cwd")) != self.cwd:
                    continue
                with open(f"/proc/{pid}/stat") as fh:
                    parts = fh.read().rsplit(")", 1)[1].split()
                out[pid] = (int(parts[11]) + int(parts[12])) / tck
            except (OSError, IndexError, ValueError):
                continue
        return out

    def _loop(self):
        while not self._stop.wait(self.period):
            for k, v in self._scan().items():
                self.maxv[k] = max(self.maxv.get(k, 0.0), v)

    def __enter__(self):
        self.base = self._scan()
        self.maxv = dict(self.base)
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, daemon=True)
        self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        for k, v in self._scan().items():
            self.maxv[k] = max(self.maxv.get(k, 0.0), v)
        self.cpu_s = sum(v - self.base.get(k, 0.0) for k, v in self.maxv.items())
        return False


def emit(record):
    """Print one JSON result line (the driver parses lines starting with RESULT)."""
    print("RESULT " + json.dumps(record), flush=True)


def timed():
    return time.perf_counter()


def log(*args):
    print(*args, file=sys.stderr, flush=True)
