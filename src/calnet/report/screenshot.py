"""A report page in headless Chromium: a screenshot for humans checking the layout, and a
render check for tests (:func:`check_page`: images that did not load, console errors).

Optional: if Chromium is not installed, :func:`screenshot` and :func:`check_page` say so
and return ``None`` (install it with ``apt-get install chromium``). Nothing in calnet's
pipeline needs it.
"""

from __future__ import annotations

import html
import json
import re
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
          "--disable-background-networking", "--disable-component-update", "--disable-sync")


def _installed(label: str, chromium: str | Path, why: str = "") -> Path | None:
    """The Chromium executable, or ``None`` with a message on stderr naming ``label``."""
    exe = Path(chromium)
    if exe.exists():
        return exe
    print(f"{label}: {exe} not found; install Chromium (apt-get install chromium){why}",
          file=sys.stderr)
    return None


def _run_chromium(label: str, exe: Path, args: Sequence[str], *,
                  timeout_s: float) -> subprocess.CompletedProcess | None:
    """Run headless Chromium with ``args`` and a throw-away profile; ``None`` (with a
    message on stderr naming ``label``) when it times out."""
    with tempfile.TemporaryDirectory(prefix="calnet-chromium-") as profile:
        try:
            return subprocess.run([str(exe), *_FLAGS, f"--user-data-dir={profile}", *args],
                                  capture_output=True, text=True, timeout=timeout_s,
                                  check=False)
        except subprocess.TimeoutExpired:
            print(f"{label}: Chromium timed out after {timeout_s} s", file=sys.stderr)
            return None


def _failed(label: str, proc: subprocess.CompletedProcess) -> None:
    tail = (proc.stderr or "").strip().splitlines()[-3:]
    print(f"{label}: Chromium failed (exit {proc.returncode}): {' | '.join(tail)}",
          file=sys.stderr)


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
    exe = _installed("screenshot", chromium, " to take screenshots")
    if exe is None:
        return None
    html_path, png_path = Path(html_path).resolve(), Path(png_path).resolve()
    png_path.parent.mkdir(parents=True, exist_ok=True)
    proc = _run_chromium("screenshot", exe, [
        f"--screenshot={png_path}", f"--window-size={int(width)},{int(height)}",
        "--hide-scrollbars", html_path.as_uri()], timeout_s=timeout_s)
    if proc is None:
        return None
    if proc.returncode != 0 or not png_path.exists():
        _failed("screenshot", proc)
        return None
    return png_path


@dataclass(frozen=True)
class PageCheck:
    """What Chromium saw when it loaded a page.

    Attributes
    ----------
    images : int
        ``<img>`` elements on the page.
    broken_images : tuple of str
        The ``alt`` text of each image that did not load (``naturalWidth`` 0).
    console : tuple of str
        Console errors and warnings, uncaught exceptions, failed loads, and every message
        Chromium wrote to the page's console (a page without scripts writes none).
    tops : dict of str -> float or None
        Top edge (CSS px from the top of the page) of each element id asked for; ``None``
        for an id the page lacks.
    """

    images: int
    broken_images: tuple[str, ...]
    console: tuple[str, ...]
    tops: dict[str, float | None]

    @property
    def ok(self) -> bool:
        return not self.broken_images and not self.console


# runs first: records errors (also failed loads of images, in the capture phase) and
# console.error/warn, without writing to the console itself
_WATCH = """<script>
window.__calnet = [];
window.addEventListener("error", e => window.__calnet.push("error: " + (e.message ||
  ("failed to load " + (e.target && e.target.tagName)))), true);
window.addEventListener("unhandledrejection", e => window.__calnet.push("rejection: " +
  e.reason));
for (const level of ["error", "warn"]) {
  console[level] = (...a) => { window.__calnet.push(level + ": " + a.join(" ")); };
}
</script>"""
# runs after the load event: writes the findings into the DOM that --dump-dom prints
_REPORT = """<script>
window.addEventListener("load", () => {
  const images = [...document.images].map(i => ({ok: i.complete && i.naturalWidth > 0,
                                                 alt: i.alt}));
  const tops = {};
  for (const id of %s) {
    const el = document.getElementById(id);
    tops[id] = el ? el.getBoundingClientRect().top + window.scrollY : null;
  }
  const pre = document.createElement("pre");
  pre.id = "calnet-page-check";
  pre.textContent = JSON.stringify({images, console: window.__calnet, tops});
  document.body.appendChild(pre);
});
</script>"""
_CONSOLE_LINE = re.compile(r":CONSOLE[:(]\d+\)?\] (.*)$", re.M)
_RESULT = re.compile(r'<pre id="calnet-page-check">(.*?)</pre>', re.S)


def check_page(html_path: str | Path, *, ids: Sequence[str] = (), width: int = 1280,
               height: int = 1000, chromium: str | Path = CHROMIUM,
               timeout_s: float = 120.0) -> PageCheck | None:
    """Load a local HTML page in headless Chromium and report what went wrong.

    A copy of the page with two small scripts (one watching for errors from the start,
    one collecting the findings after the load event) is loaded with ``--dump-dom``;
    Chromium's own console log (``--enable-logging=stderr``) adds the messages the
    browser writes to the console (blocked loads, security errors).

    Parameters
    ----------
    html_path : str or Path
        The page, e.g. ``out/report.html``.
    ids : sequence of str
        Element ids whose position to report (e.g. ``"headline"``).
    width, height : int
        Window size in CSS pixels.
    chromium : str or Path
        The Chromium executable.
    timeout_s : float
        Give up after this many seconds.

    Returns
    -------
    PageCheck or None
        ``None`` (with a message on stderr) when Chromium is absent or fails.
    """
    exe = _installed("check_page", chromium)
    if exe is None:
        return None
    page = Path(html_path).read_text(encoding="utf-8")
    page = re.sub(r"<head>", lambda m: m.group(0) + _WATCH, page, count=1)
    report = _REPORT % json.dumps(list(ids))
    page = (page.replace("</body>", report + "</body>", 1) if "</body>" in page
            else page + report)
    with tempfile.TemporaryDirectory(prefix="calnet-page-") as tmp:
        copy = Path(tmp) / "page.html"
        copy.write_text(page, encoding="utf-8")
        proc = _run_chromium("check_page", exe, [
            "--enable-logging=stderr", "--v=0", "--virtual-time-budget=10000",
            f"--window-size={int(width)},{int(height)}", "--dump-dom", copy.as_uri()],
            timeout_s=timeout_s)
    if proc is None:
        return None
    found = _RESULT.search(proc.stdout or "")
    if proc.returncode != 0 or found is None:
        _failed("check_page", proc)
        return None
    doc = json.loads(html.unescape(found.group(1)))
    console = list(doc["console"]) + _CONSOLE_LINE.findall(proc.stderr or "")
    return PageCheck(images=len(doc["images"]),
                     broken_images=tuple(i["alt"] for i in doc["images"] if not i["ok"]),
                     console=tuple(dict.fromkeys(console)), tops=dict(doc["tops"]))
