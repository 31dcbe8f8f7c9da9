"""Toy simulators for the campaign tests (milliseconds each).

Referenced from specs as ``python:toy_sims:<function>``; worker processes import this
module through ``PYTHONPATH`` (the tests set it to this folder).
"""

from __future__ import annotations

import math
import os
import sys
import time

from calnet.simulators.base import SimResult

VERSION = "toy-1"


def quadratic(inputs, *, scale=1.0):
    """``y = scale * (x^2 + a x + b)``, ``z = x - b``."""
    x, a, b = inputs["x"], inputs["a"], inputs["b"]
    return {"y": scale * (x * x + a * x + b), "z": x - b}


def crashy(inputs):
    """Raises for ``x > 0.7``."""
    if inputs["x"] > 0.7:
        raise RuntimeError(f"solver diverged at x={inputs['x']:.3f}")
    return quadratic(inputs)


def hangs(inputs):
    """Sleeps forever for ``x < 0.2``."""
    if inputs["x"] < 0.2:
        while True:
            time.sleep(1)
    return quadratic(inputs)


def nan_out(inputs):
    """Returns NaN for ``y`` when ``x`` is in (0.4, 0.6)."""
    out = quadratic(inputs)
    if 0.4 < inputs["x"] < 0.6:
        out["y"] = math.nan
    return out


def nonconverged(inputs):
    """A SimResult with status ``nonconverged`` for ``a < 0.3``."""
    out = quadratic(inputs)
    if inputs["a"] < 0.3:
        return SimResult(out, "nonconverged", "residual 1e-2 after 100 iterations")
    return SimResult(out)


def wrong_type(inputs, *, kind="str"):
    """``quadratic`` with ``y`` of another type (``kind``): a string, a list, a 1-element
    array, a string that reads as a number (``numstr``), a SimResult holding one, or
    (numbers, accepted) NumPy scalars."""
    import numpy as np

    out = quadratic(inputs)
    y = {"str": "abc", "list": [1.0, 2.0], "array": np.array([1.5]), "result": "1.5",
         "numstr": "1.5", "numpy": np.float32(1.5), "0-d": np.array(1.5)}[kind]
    return SimResult({**out, "y": y}) if kind == "result" else {**out, "y": y}


def misnamed(inputs, *, shape="extra"):
    """``quadratic`` with an output the spec does not declare beside ``y`` and ``z``
    (``extra``: ``residual``, and ``iterations`` for ``x > 0.6``), or with ``y`` under
    another name (``renamed``: ``yy``)."""
    out = quadratic(inputs)
    if shape == "renamed":
        return {"yy": out.pop("y"), **out}
    return {**out, "residual": 1e-6, **({"iterations": 3} if inputs["x"] > 0.6 else {})}


def chatty(inputs):
    """``quadratic``, printing 500 lines of a solver's log on standard output and a
    warning on standard error, from Python and from the C library (as compiled code
    would)."""
    import ctypes

    for i in range(500):
        print("iteration", i, "residual", 1.0 / (i + 1))
    print("warning: mesh is coarse", file=sys.stderr)
    sys.stdout.flush()
    ctypes.CDLL(None).puts(b"from C")
    return quadratic(inputs)


def killed_once(inputs, *, marker):
    """``quadratic``, except that the first call (the file ``marker`` does not exist
    yet: it creates it) kills its own process with SIGKILL, as ``kill -9`` would."""
    import signal

    if not os.path.exists(marker):
        open(marker, "w").close()
        time.sleep(0.5)  # the next run is handed out meanwhile: two runs are in flight
        os.kill(os.getpid(), signal.SIGKILL)
    return quadratic(inputs)


def dies(inputs):
    """Kills its own process for ``x > 0.9`` (a hard crash, not an exception)."""
    if inputs["x"] > 0.9:
        os._exit(7)
    return quadratic(inputs)


def deaf_sleeper_or_dies(role, marker):
    """For the executor tests. ``deaf`` ignores SIGTERM (as some simulators do) and, when
    the file ``marker`` does not exist yet, writes it and sleeps for a minute; ``dies``
    waits for ``marker``, then ends its process with exit code 7."""
    import signal
    from pathlib import Path

    path = Path(marker)
    if role == "deaf":
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if not path.exists():
            path.write_text("started")
            time.sleep(60)
        return "deaf done"
    end = time.monotonic() + 30
    while not path.exists() and time.monotonic() < end:
        time.sleep(0.01)
    os._exit(7)


def broken(inputs):
    """Raises at every point (a simulator that cannot work)."""
    raise RuntimeError("license server unreachable")


def exits(inputs):
    """Calls ``sys.exit(4)`` for ``x > 0.9`` (how a script-style simulator gives up)."""
    if inputs["x"] > 0.9:
        sys.exit(4)
    return quadratic(inputs)


def slower(inputs):
    """``quadratic`` after 0.5 s (the Ctrl-C test: the campaign must still be running
    when the signal arrives, even on a loaded machine)."""
    time.sleep(0.5)
    return quadratic(inputs)


def slow(inputs):
    """``quadratic`` after 0.1 s (the kill -9 test)."""
    time.sleep(0.1)
    return quadratic(inputs)


def counted(inputs):
    """``quadratic`` after 0.2 s, appending one line per execution to the file named by
    ``$TOY_COUNT_FILE`` (the two-writers test counts executions). With
    ``$TOY_RELEASE_FILE`` set, each run first waits (up to 120 s) for that file to exist,
    so that a campaign is still running while the test starts a second one."""
    with open(os.environ["TOY_COUNT_FILE"], "a") as fh:
        fh.write(f"{inputs['x']!r}\n")
    release = os.environ.get("TOY_RELEASE_FILE")
    deadline = time.monotonic() + 120
    while release and not os.path.exists(release) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.2)
    return quadratic(inputs)


def sleeper(inputs):
    """Starts ``sleep 61`` and waits for it (a run that hangs, with a child of its own)."""
    import subprocess

    subprocess.run(["sleep", "61"], check=False)
    return quadratic(inputs)


def busy(inputs):
    """Computes for 60 s (NumPy, no sleeping) for ``x < 0.5``, else returns at once."""
    import numpy as np

    if inputs["x"] < 0.5:
        end, a = time.monotonic() + 60, np.eye(200)
        while time.monotonic() < end:
            a = np.linalg.inv(a @ a.T + np.eye(200))
    return quadratic(inputs)


def chain_m1(inputs):
    """``w1 = 0.5 + 0.4 sin(2 x)`` for x in [0, 1]: w1 lands in [0.5, 0.87]."""
    return {"w1": 0.5 + 0.4 * math.sin(2.0 * inputs["x"])}


def chain_m2(inputs):
    """``w2 = w1^2 + c``."""
    return {"w2": inputs["w1"] ** 2 + inputs.get("c", 0.0)}


def chain_m3(inputs):
    """``y = w1 + w2``."""
    return {"y": inputs["w1"] + inputs["w2"]}


def deaf_hang(inputs, *, pid_file):
    """Ignores SIGTERM and SIGINT, writes its process id to ``pid_file`` and hangs for
    ever (a simulator that nothing but SIGKILL stops)."""
    import signal

    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with open(pid_file, "w") as f:
        f.write(str(os.getpid()))
    while True:
        time.sleep(1)


def raises_interrupt(inputs):
    """Raises KeyboardInterrupt itself (no signal) for ``x > 0.5``."""
    if inputs["x"] > 0.5:
        raise KeyboardInterrupt("solver caught Ctrl-C")
    return quadratic(inputs)


def interrupted_by_user(inputs):
    """Sends SIGINT to its own process, as a Ctrl-C at the terminal would."""
    import signal

    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(5)
    return quadratic(inputs)


def dies_logged(inputs, *, log):
    """Appends ``x`` to the file ``log``, then ends its process for ``x > 0.75``."""
    with open(log, "a") as f:
        f.write(f"{inputs['x']!r}\n")
    time.sleep(0.2)  # the next run is queued meanwhile
    if inputs["x"] > 0.75:
        os._exit(7)
    return quadratic(inputs)


_CALLS = [0]


def leaks(inputs):
    """Runs out of memory from its third call in a process on (a leak)."""
    _CALLS[0] += 1
    if _CALLS[0] >= 3:
        raise MemoryError
    return quadratic(inputs)


def odd_outputs(inputs, *, kind):
    """Returns ``y`` as a bool, None, NaN, infinity or an integer too large for a float,
    by ``kind``."""
    value = {"bool": True, "none": None, "nan": math.nan, "inf": -math.inf,
             "huge": 10**400}[kind]
    return {"y": value, "z": 1.0}


def extras(inputs, *, kind):
    """``quadratic`` and an output the spec does not declare that is no finite number
    (``kind``: NaN, a text, an array, a bool, None, an integer too large for a float)."""
    import numpy as np

    value = {"nan": math.nan, "text": "converged", "array": np.zeros(3), "bool": True,
             "none": None, "huge": -(10**400)}[kind]
    return {**quadratic(inputs), "extra": value}


def moves(inputs, *, to):
    """``quadratic``, after changing the working directory to ``to``."""
    os.chdir(to)
    return quadratic(inputs)


def blas_threads(_):
    """The OPENBLAS_NUM_THREADS this worker sees and its BLAS libraries' largest thread
    count (NumPy's and SciPy's OpenBLAS, loaded here)."""
    import scipy.linalg  # noqa: F401  (loads SciPy's BLAS)
    from threadpoolctl import threadpool_info

    return (os.environ.get("OPENBLAS_NUM_THREADS"),
            max(lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"))
