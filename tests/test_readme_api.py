"""The README's Python-API example runs as written, from the repository root."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
@pytest.mark.integration
def test_readme_python_example_runs():
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert len(blocks) == 1, "expected one python block in README.md"
    proc = subprocess.run([sys.executable, "-c", blocks[0]], cwd=ROOT, capture_output=True,
                          text=True, timeout=900,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert any(line.startswith("melt_pool.") for line in lines), proc.stdout
    assert any(line.startswith("solidification.") for line in lines), proc.stdout
    mean, lower, upper = (float(re.search(r"\[\s*([-0-9.e+]+)\s*\]", part).group(1))
                          for part in re.findall(r"\[[^\]]*\]", lines[-1]))
    assert lower < mean < upper and 20 < mean < 1000  # a width in um, not a crash
