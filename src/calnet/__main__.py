"""``python -m calnet ...``: the ``calnet`` command."""

from calnet.cli import app

if __name__ == "__main__":
    app(prog_name="calnet")
