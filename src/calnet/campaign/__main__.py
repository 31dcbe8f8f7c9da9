"""``python -m calnet.campaign SPEC ...``: the campaign command on its own.

The same command as ``calnet campaign`` (useful for batch jobs and for tests that start
a campaign in a separate process).
"""

import typer

from calnet.campaign.command import campaign
from calnet.cli import user_errors

app = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
app.command()(user_errors(campaign))

if __name__ == "__main__":
    app()
