"""``python -m calnet.campaign SPEC ...``: the campaign command on its own.

The same command as ``calnet campaign`` (useful for batch jobs and for tests that start
a campaign in a separate process).
"""

from calnet.campaign.command import campaign
from calnet.cli import App, user_errors

app = App()
app.command()(user_errors(campaign))

if __name__ == "__main__":
    app()
