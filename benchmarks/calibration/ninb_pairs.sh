#!/usr/bin/env bash
# calnet run examples/ninb with a cold compilation cache, three times each for BASE_COMMIT
# (a detached worktree, with its own examples/ninb) and the checkout, interleaved so that both
# see the same machine.
# One line per run: code, run, wall s, user s, sys s, peak RSS KB, then from run_info.json
# surrogates, calibration, sampler compile, sampling, prediction, validation, report, total.
# Usage (repository root): benchmarks/calibration/ninb_pairs.sh BASE_COMMIT [RUNS]
set -euo pipefail
base=${1:?usage: ninb_pairs.sh BASE_COMMIT [RUNS]}
runs=${2:-3}
cd "$(dirname "$0")/../.."
wt=$(mktemp -d)/base
git worktree add --detach "$wt" "$base" >/dev/null 2>&1
trap 'git worktree remove --force "$wt"' EXIT
for i in $(seq 1 "$runs"); do
    for who in base current; do
        root=$([ "$who" = base ] && echo "$wt" || echo "$PWD")
        out=$(mktemp -d)/ninb
        CALNET_JAX_CACHE=off PYTHONPATH=$root/src /usr/bin/time -f "%e %U %S %M" \
            -o "$out.time" .venv/bin/python -m calnet run "$root/examples/ninb" --out "$out" \
            >/dev/null 2>&1
        stages=$(.venv/bin/python - "$out/run_info.json" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
t, c = d["timings_s"], next(iter(d["calibration_stages"].values()))
print(t["surrogates"], t["calibration"], round(c["compile_s"], 1), round(c["sampling_s"], 1),
      t["prediction"], t["validation"], t["report"], t["total"])
PY
)
        echo "$who $i $(tail -1 "$out.time") $stages"
    done
done
