"""Prediction error through a three-model chain: chain-aware vs per-box LHS designs.

M1: x -> w1, M2: w1 -> w2 (a sharp step), M3: (w1, w2) -> y (``chain_sims.py``), with
10 / 15 / 15 runs and no parameters. The declared boxes of the linked inputs (w1 in
[-1, 2], w2 in [-2, 3]) are much wider than where the upstream outputs land, as a user
who does not know that yet would declare them. For each seed:

* ``chain``: ``calnet campaign`` with ``design: chain`` for M2 and M3 (M1 a Latin
  hypercube);
* ``lhs``: ``design: lhs`` for every model (a Latin hypercube over each box);
* ``single GP``: one GP of x -> y on a 15-point Latin hypercube of composite runs.

Each model's GP is ``calnet.surrogates.fit_gp`` on its store's runs
(``calnet.campaign.load_runs``); the chain predicts ``y`` at a 300-point grid of x in
[0, 1] by composing the GP means (w1 = GP1(x), w2 = GP2(w1), y = GP3(w1, w2)). NRMSE is
the RMSE over the grid divided by the range of the true y there. Usage, from the
repository root (with ``src`` importable)::

    python benchmarks/chain/run.py --seeds 10 --step 0.05
    python benchmarks/chain/run.py --seeds 10 --step 0.02
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml
from scipy.stats import qmc

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import chain_sims  # noqa: E402

from calnet.campaign import load_runs, run_campaign  # noqa: E402
from calnet.spec import load_spec  # noqa: E402
from calnet.surrogates import fit_gp  # noqa: E402

RUNS = {"M1": 10, "M2": 15, "M3": 15}
BOXES = {"x": (0.0, 1.0), "w1": (-1.0, 2.0), "w2": (-2.0, 3.0)}
GRID = np.linspace(0.0, 1.0, 300)


def spec(design: str, seed: int, step: float) -> dict:
    def box(*names):
        return {n: {"lower": BOXES[n][0], "upper": BOXES[n][1]} for n in names}

    def model(sim, inputs, output, design_):
        options = {"step": step} if sim == "m2" else {}
        return {"simulator": {"kind": "python", "target": f"chain_sims:{sim}",
                              "options": options}, "inputs": box(*inputs),
                "outputs": {output: {}},
                "campaign": {"runs": RUNS[sim.upper()], "design": design_}}

    return {"name": "chain_benchmark", "settings": {"seed": seed},
            "models": {"M1": model("m1", ["x"], "w1", "lhs"),
                       "M2": model("m2", ["w1"], "w2", design),
                       "M3": model("m3", ["w1", "w2"], "y", design)},
            "links": [{"from": "M1.w1", "to": "M2.w1"}, {"from": "M1.w1", "to": "M3.w1"},
                      {"from": "M2.w2", "to": "M3.w2"}]}


def truth(x: np.ndarray, step: float) -> np.ndarray:
    return np.array([chain_sims.f3(chain_sims.f1(v), chain_sims.f2(chain_sims.f1(v), step))
                     for v in x])


def gp_of(network, name: str, output: str, seed: int):
    runs = load_runs(network, name)
    model = network.model(name)
    lower = np.array([v.lower for v in model.inputs])
    upper = np.array([v.upper for v in model.inputs])
    return fit_gp(runs.X, runs.Y[output], lower=lower, upper=upper, seed=seed, name=output)


def chain_nrmse(design: str, seed: int, step: float, folder: Path) -> float:
    folder.mkdir(parents=True)
    (folder / "network.yaml").write_text(yaml.safe_dump(spec(design, seed, step)))
    network = load_spec(folder)
    for name in network.order:
        run_campaign(network, name, executor="in-process", progress=False)
    g1, g2, g3 = (gp_of(network, m, o, seed) for m, o in
                  (("M1", "w1"), ("M2", "w2"), ("M3", "y")))
    w1 = np.asarray(g1.predict(GRID[:, None])[0])
    w2 = np.asarray(g2.predict(w1[:, None])[0])
    y = np.asarray(g3.predict(np.column_stack([w1, w2]))[0])
    return nrmse(y, step)


def single_gp_nrmse(seed: int, step: float) -> float:
    x = qmc.LatinHypercube(d=1, rng=np.random.default_rng(seed)).random(RUNS["M2"])
    gp = fit_gp(x, truth(x[:, 0], step), lower=np.array([0.0]), upper=np.array([1.0]),
                seed=seed)
    return nrmse(np.asarray(gp.predict(GRID[:, None])[0]), step)


def nrmse(pred: np.ndarray, step: float) -> float:
    y = truth(GRID, step)
    return float(np.sqrt(np.mean((pred - y) ** 2)) / np.ptp(y))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--step", type=float, default=0.05, help="M2's step scale")
    parser.add_argument("--out", help="JSON file of the per-seed results")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            row = {"seed": seed, "step": args.step,
                   "chain": chain_nrmse("chain", seed, args.step, Path(tmp) / f"c{seed}"),
                   "lhs": chain_nrmse("lhs", seed, args.step, Path(tmp) / f"l{seed}"),
                   "single_gp": single_gp_nrmse(seed, args.step)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1) + "\n")
    print("\n| design | NRMSE mean | sd | min | max |\n|---|---:|---:|---:|---:|")
    for key, label in (("chain", "chain-aware (M2, M3)"), ("lhs", "per-box LHS"),
                       ("single_gp", "single GP x -> y (15 runs)")):
        v = np.array([r[key] for r in rows])
        print(f"| {label} | {v.mean():.2%} | {v.std(ddof=1):.2%} | {v.min():.2%} | "
              f"{v.max():.2%} |")
    ratio = np.array([r["lhs"] / r["chain"] for r in rows])
    print(f"\nper-box LHS / chain-aware NRMSE, per seed: median {np.median(ratio):.2f}, "
          f"min {ratio.min():.2f}, max {ratio.max():.2f}")


if __name__ == "__main__":
    main()
