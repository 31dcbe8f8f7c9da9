"""Helpers of the campaign tests: small networks around the toy simulators."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent


def toy_spec(folder: Path, simulator: str | dict = "python:toy_sims:quadratic", *,
             runs: int = 12, timeout: float | None = None, seed: int = 0,
             x_upper: float = 1.0, x_scale: str = "linear") -> Path:
    """Write a one-model spec (inputs x; parameters a, b; outputs y, z) and return it."""
    model = {"simulator": simulator,
             "inputs": {"x": {"lower": 0.0 if x_scale == "linear" else 0.01,
                              "upper": x_upper, "scale": x_scale}},
             "parameters": {"a": {"lower": 0.0, "upper": 1.0}, "b": {"lower": -1.0, "upper": 1.0}},
             "outputs": {"y": {}, "z": {}},
             "campaign": {"runs": runs, **({"timeout": timeout} if timeout else {})}}
    spec = {"name": "toy", "models": {"toy": model}, "settings": {"seed": seed}}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "network.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def store_rows(path: Path, *, drop=("wall_time", "started_at", "finished_at")) -> list[tuple]:
    """Every row of a store, by index, without the columns that record time."""
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as db:
        cur = db.execute("SELECT * FROM runs ORDER BY idx")
        names = [d[0] for d in cur.description]
        keep = [i for i, n in enumerate(names) if n not in drop]
        rows = [tuple(r[i] for i in keep) for r in cur]
    db.close()
    return rows


def toy_network(folder: Path, simulator: str | dict = "python:toy_sims:quadratic", **kw):
    """Load the spec written by :func:`toy_spec`."""
    from calnet.spec import load_spec

    return load_spec(toy_spec(folder, simulator, **kw))


def campaign_app():
    """A Typer app with the ``campaign`` command as the CLI registers it (and another
    command, so that the app dispatches by name)."""
    import typer

    from calnet.cli import campaign_command

    app = typer.Typer()
    app.command("campaign")(campaign_command())
    app.command("other")(lambda: None)
    return app


def chain_spec(folder: Path, *, runs=(8, 10, 10), design: str | None = None,
               w1_box: tuple[float, float] = (-2.0, 3.0)) -> Path:
    """Write a three-model chain (M1: x -> w1; M2: (w1, c) -> w2 with a parameter c;
    M3: (w1, w2) -> y), the linked inputs' boxes much wider than where they land."""
    def model(sim, inputs, outputs, n, parameters=None):
        body = {"simulator": f"python:toy_sims:{sim}", "inputs": inputs,
                "outputs": {o: {} for o in outputs},
                "campaign": {"runs": n, **({"design": design} if design else {})}}
        return {**body, **({"parameters": parameters} if parameters else {})}

    spec = {"name": "chain", "settings": {"seed": 0},
            "models": {
                "M1": model("chain_m1", {"x": {"lower": 0.0, "upper": 1.0}}, ["w1"], runs[0]),
                "M2": model("chain_m2", {"w1": {"lower": w1_box[0], "upper": w1_box[1]}},
                            ["w2"], runs[1],
                            {"c": {"lower": 0.0, "upper": 0.1}}),
                "M3": model("chain_m3", {"w1": {"lower": -2.0, "upper": 3.0},
                                         "w2": {"lower": -1.0, "upper": 9.0}}, ["y"], runs[2])},
            "links": [{"from": "M1.w1", "to": "M2.w1"}, {"from": "M1.w1", "to": "M3.w1"},
                      {"from": "M2.w2", "to": "M3.w2"}]}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "network.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path
