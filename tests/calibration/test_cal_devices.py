"""Start-up settings: XLA host devices and the on-disk compilation cache."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from calnet.calibration.devices import enable_compilation_cache


def test_compilation_cache_folder_from_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("CALNET_JAX_CACHE", raising=False)
    assert enable_compilation_cache() == str(tmp_path / "calnet" / "jax")

    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR")
    monkeypatch.setenv("CALNET_JAX_CACHE", str(tmp_path / "mine"))
    assert enable_compilation_cache() == str(tmp_path / "mine")


def test_compilation_cache_off_and_user_setting_wins(monkeypatch, tmp_path):
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("CALNET_JAX_CACHE", "off")
    assert enable_compilation_cache() is None
    monkeypatch.setenv("CALNET_JAX_CACHE", "")
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "theirs"))
    assert enable_compilation_cache() == str(tmp_path / "theirs")


def test_the_command_configures_host_devices_and_importing_it_does_not():
    """Importing calnet.cli starts nothing; running a command asks XLA for 4 host devices
    before jax starts (``calnet run`` samples its chains in parallel on them)."""
    code = (
        "import os, sys\n"
        "os.environ.pop('XLA_FLAGS', None)\n"
        "import calnet.cli\n"
        "assert 'jax' not in sys.modules and 'XLA_FLAGS' not in os.environ\n"
        "from typer.testing import CliRunner\n"
        "args = ['simulate', 'solidification', '--set', 'S=0.3', '--set', 'G=1e7']\n"
        "result = CliRunner().invoke(calnet.cli.app, args)\n"
        "assert result.exit_code == 0, result.output\n"
        "import jax\n"
        "print(jax.local_device_count(), jax.numpy.ones(1).dtype)\n"
    )
    env = {**os.environ, "CALNET_JAX_CACHE": "off"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["4", "float64"]


def test_asking_for_devices_after_jax_started_is_warned_of():
    """From Python, a call after jax started cannot take effect: the chains then run one
    after another, with other draws than the command line's for the same seed."""
    import jax

    from calnet.calibration.devices import configure_host_devices

    jax.devices()  # started
    have = jax.local_device_count()
    with pytest.warns(UserWarning, match=rf"configure_host_devices\({have + 1}\) came after "
                                         rf"jax started with {have} device\(s\): chains run "
                                         "one after another"):
        report = configure_host_devices(have + 1)
    assert not report.applied and report.how == "too late"
