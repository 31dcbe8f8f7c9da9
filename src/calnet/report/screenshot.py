"""Screenshot of a report page with headless Chromium, for humans checking the layout.

Optional: if Chromium is not installed, :func:`screenshot` says so and returns ``None``
(install it with ``apt-get install chromium``). Nothing in calnet's pipeline needs it.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"


def screenshot(html_path: str | Path, png_path: str | Path, width: int = 1280,
               height: int = 2400, *, chromium: str | Path = CHROMIUM,
               timeout_s: float = 120.0) -> Path | None:
    """Render a local HTML file to a PNG of ``width`` x ``height`` pixels.

    Parameters
    ----------
    html_path : str or Path
        The page, e.g. ``out/report.html``.
    png_path : str or Path
        Destination PNG.
    width, height : int
        Window size in CSS pixels; the page is cut at ``height``.
    chromium : str or Path
        The Chromium executable.
    timeout_s : float
        Give up after this many seconds.

    Returns
    -------
    Path or None
        The PNG, or ``None`` (with a message on stderr) when Chromium is absent or fails.
    """
    exe = Path(chromium)
    if not exe.exists():
        print(f"screenshot: {exe} not found; install Chromium (apt-get install chromium) "
              "to take screenshots", file=sys.stderr)
        return None
    html_path, png_path = Path(html_path).resolve(), Path(png_path).resolve()
    png_path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="calnet-chromium-") as profile:
        cmd = [str(exe), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", f"--user-data-dir={profile}",
               f"--screenshot={png_path}", f"--window-size={int(width)},{int(height)}",
               "--hide-scrollbars", html_path.as_uri()]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s,
                                  check=False)
        except subprocess.TimeoutExpired:
            print(f"screenshot: Chromium timed out after {timeout_s} s", file=sys.stderr)
            return None
    if proc.returncode != 0 or not png_path.exists():
        tail = (proc.stderr or "").strip().splitlines()[-3:]
        print(f"screenshot: Chromium failed (exit {proc.returncode}): {' | '.join(tail)}",
              file=sys.stderr)
        return None
    return png_path
