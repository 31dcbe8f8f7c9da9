"""Start-up settings: XLA host devices and the on-disk compilation cache."""

from __future__ import annotations

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
