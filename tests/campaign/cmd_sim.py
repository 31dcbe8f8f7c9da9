"""A toy external simulator for the command-runner tests (run as a script).

Modes (first argument):
  json  IN OUT        read inputs from the JSON file IN, write outputs to the JSON file OUT
  args  X A B         inputs as arguments, outputs as JSON on stdout
  echo  TEXT OUT      write {"y": len(TEXT), "z": 0} and TEXT itself (to check quoting)
  fail                exit with code 3 and a message on stderr
  hang                sleep for a minute
  status              print outputs on stdout with a status calnet does not know
  strnum              print outputs on stdout with y a string ("1.5") and a text note
  chatty X A B        like args, between lines of a solver's log (one a JSON object too)
  nojson              print 300 lines of a solver's log and no JSON object
  killed              kill itself with SIGKILL
  huge                print outputs on stdout with y an integer too large for a float
  extra               print outputs on stdout with an undeclared NaN and a text
  noout               write nothing, exit with code 0
"""

import json
import os
import signal
import sys
import time


def outputs(x: float, a: float, b: float) -> dict:
    return {"y": x * x + a * x + b, "z": x - b}


def main(argv: list[str]) -> None:
    mode = argv[0]
    if mode == "json":
        inputs = json.loads(open(argv[1]).read())
        with open(argv[2], "w") as fh:
            json.dump(outputs(inputs["x"], inputs["a"], inputs["b"]), fh)
    elif mode == "args":
        print(json.dumps(outputs(*map(float, argv[1:4]))))
    elif mode == "echo":
        with open(argv[2], "w") as fh:
            json.dump({"y": len(argv[1]), "z": 0.0}, fh)
        with open(argv[2] + ".txt", "w") as fh:
            fh.write(argv[1])
    elif mode == "fail":
        print("mesh generation failed", file=sys.stderr)
        sys.exit(3)
    elif mode == "status":
        print(json.dumps({"y": 1.0, "z": 0.0, "status": "exploded", "message": "mesh tangled"}))
    elif mode == "strnum":
        print(json.dumps({"y": "1.5", "z": 0.0, "note": "converged in 3 steps"}))
    elif mode == "chatty":
        print("solver 2.1 starting\n{ not json }")
        print(json.dumps({"y": -1.0, "z": -1.0}))  # an earlier object: not the outputs
        print("[1, 2]\n" + json.dumps(outputs(*map(float, argv[1:4]))) + "\ndone.")
    elif mode == "nojson":
        print("\n".join(f"iteration {i} residual {1 / (i + 1):.3e}" for i in range(300)))
    elif mode == "hang":
        time.sleep(60)
    elif mode == "killed":
        os.kill(os.getpid(), signal.SIGKILL)
    elif mode == "huge":
        print('{"y": ' + "9" * 400 + ', "z": 0.0}')
    elif mode == "extra":
        print('{"y": 1.5, "z": 0.0, "residual": NaN, "label": "converged"}')


if __name__ == "__main__":
    main(sys.argv[1:])
