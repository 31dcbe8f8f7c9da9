"""``python -m calnet ...``: the ``calnet`` command."""

from calnet.cli import main

if __name__ == "__main__":
    main(prog_name="calnet")
