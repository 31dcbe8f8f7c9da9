"""A full or read-only disk: one line naming the path and the cause, exit code 1, and
the files as they were (never half-written, never advice to delete a store)."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess

import pytest
from campaign_helpers import campaign_app, toy_spec
from typer.testing import CliRunner

from calnet.campaign.store import RunStore
from calnet.errors import CalnetError
from calnet.files import replacing


@pytest.fixture
def disk(tmp_path):
    """A 1 MiB tmpfs of its own (needs root and mount; skipped elsewhere)."""
    folder = tmp_path / "disk"
    folder.mkdir()
    if shutil.which("mount") is None or os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root and mount(8)")
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(folder)],
                          capture_output=True, text=True)
    if made.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {made.stderr.strip()}")
    yield folder
    subprocess.run(["umount", "-l", str(folder)], check=False)


def _fill(folder) -> None:
    """Write a file until the disk is full."""
    with open(folder / "filler", "wb", buffering=0) as fh:
        try:
            while True:
                fh.write(b"\0" * 4096)
        except OSError as err:
            assert err.errno == errno.ENOSPC


def _remount(folder, mode: str) -> None:
    subprocess.run(["mount", "-o", f"remount,{mode}", str(folder)], check=True)


def _campaign(spec, *args):
    out = CliRunner().invoke(campaign_app(), ["campaign", str(spec), "--no-progress",
                                              *map(str, args)])
    return out.exit_code, " ".join(out.output.split())


@pytest.mark.parametrize("trouble", ["full", "read-only"])
def test_an_unwritable_store_is_kept_and_the_cause_named(tmp_path, disk, trouble):
    spec = toy_spec(tmp_path, runs=3)
    store = disk / "toy.sqlite"
    assert _campaign(spec, "--store", store)[0] == 0
    with RunStore(store, readonly=True) as db:
        before = db.rows()
    _fill(disk) if trouble == "full" else _remount(disk, "ro")
    code, output = _campaign(spec, "--store", store, "--runs", 6)
    assert code == 1, output
    assert f"cannot write the campaign store '{store}'" in output
    assert ("no space left" if trouble == "full" else "read-only") in output
    assert "remove" not in output and "Traceback" not in output
    (disk / "filler").unlink() if trouble == "full" else _remount(disk, "rw")
    code, output = _campaign(spec, "--store", store, "--runs", 6)
    assert code == 0, output
    with RunStore(store, readonly=True) as db:
        assert db.rows()[:3] == before and db.status_counts() == {"ok": 6}


def test_a_new_store_in_a_read_only_folder_is_not_said_to_be_kept(tmp_path, disk):
    spec = toy_spec(tmp_path, runs=3)
    _remount(disk, "ro")
    try:
        code, output = _campaign(spec, "--store", disk / "toy.sqlite")
    finally:
        _remount(disk, "rw")
    assert code == 1, output
    assert f"cannot create the campaign store '{disk / 'toy.sqlite'}'" in output
    assert "pass a --store in a writable folder" in output
    assert "kept as it is" not in output and "Traceback" not in output


def test_an_export_to_a_full_disk_leaves_the_old_file(tmp_path, disk):
    spec = toy_spec(tmp_path, runs=3)
    out = disk / "runs.csv"
    out.write_text("an older export\n")
    _fill(disk)
    code, output = _campaign(spec, "--export", out)
    assert code == 1, output
    assert f"cannot write '{out}': no space left on the device" in output
    assert out.read_text() == "an older export\n"
    assert sorted(p.name for p in disk.iterdir()) == ["filler", "runs.csv"]  # no temp file


def test_predictions_and_surrogates_on_a_full_disk(disk):
    import numpy as np

    from calnet.cli import _write_predictions
    from calnet.surrogates.fit import fit_gp
    from calnet.surrogates.persist import save_gp

    _fill(disk)
    results = [{"dataset": "d", "observes": "m.y", "inputs": ["m.x"], "x": [[1.0]],
                "mean": [2.0], "lower95": [1.0], "upper95": [3.0]}]
    with pytest.raises(CalnetError, match="cannot write '.*pred.csv': no space left"):
        _write_predictions(disk / "pred.csv", results, [{}])
    x = np.linspace(0.0, 1.0, 6)[:, None]
    gp = fit_gp(x, np.sin(3 * x[:, 0]), lower=[0.0], upper=[1.0], n_restarts=0, name="y")
    with pytest.raises(CalnetError, match="cannot write '.*y.npz': no space left"):
        save_gp(gp, disk / "y")
    assert sorted(p.name for p in disk.iterdir()) == ["filler"]  # no 0-byte file


def test_a_failed_replace_keeps_the_old_file(tmp_path, monkeypatch):
    """Without a small disk to fill: ``os.replace`` failing as on a read-only folder."""
    target = tmp_path / "table.csv"
    target.write_text("old\n")

    def refuse(src, dst):
        raise OSError(errno.EROFS, "Read-only file system", str(dst))

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(CalnetError, match="cannot write '.*table.csv': the file system is "
                                          "read-only"), replacing(target) as tmp:
        tmp.write_text("new\n")
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["table.csv"]
