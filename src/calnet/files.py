"""Writing result files safely: all of a file or none of it, and one line on failure.

:func:`replacing` hands a writer a temporary path beside the target and moves the
finished file over the target (``os.replace``, atomic within a folder), so a full or
read-only disk leaves the previous file, or none, never a truncated one. An
``OSError`` while writing becomes a :class:`~calnet.errors.CalnetError` naming the path
and the cause (:func:`write_error`).
"""

from __future__ import annotations

import errno
import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from calnet.errors import CalnetError

_CAUSES = {
    errno.ENOSPC: "no space left on the device (free some space, or write to another "
                  "folder)",
    errno.EDQUOT: "disk quota exceeded (free some space, or write to another folder)",
    errno.EROFS: "the file system is read-only (write to another folder)",
    errno.EACCES: "permission denied (make the folder writable, or write to another "
                  "folder)",
    errno.EPERM: "permission denied (make the folder writable, or write to another "
                 "folder)",
}


def write_cause(err: OSError) -> str | None:
    """The cause of a failed write in words where it is one of the known ones (a full
    disk, a read-only file system, no permission), else None."""
    return _CAUSES.get(err.errno)


def why(err: OSError) -> str:
    """The cause of a failed write, with its remedy, in words."""
    return write_cause(err) or f"{err.strerror or err} (check the folder and the disk)"


def write_error(path: str | Path, err: OSError) -> CalnetError:
    """The one-line error of a file that could not be written."""
    return CalnetError(f"cannot write '{path}': {why(err)}")


def shown_path(path: str | Path, root: str | Path) -> str:
    """``path`` as a message names it: relative to the spec's folder ``root`` where it lies
    inside it, else its file name. A message kept in a result (``metrics.json``) then reads
    the same wherever the spec folder and the output folder are."""
    path, root = Path(path).resolve(), Path(root).resolve()
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return path.name


def make_folder(path: str | Path) -> Path:
    """``mkdir -p path``; a CalnetError naming it when it cannot be made."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise write_error(path, err) from None
    return path


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary path to write ``path``'s new content to, moved over ``path`` when the
    block ends without an error and deleted otherwise.

    The temporary file is in the same folder, with the same suffix (writers that pick a
    format by suffix, such as ``savefig`` or ``np.savez``, see the right one).

    Raises
    ------
    CalnetError
        For an ``OSError`` (no space left, read-only, permission denied), naming ``path``.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        with open(tmp, "rb+") as fh:  # on the disk before it replaces the old file
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as err:
        raise write_error(path, err) from None
    finally:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass


INCOMPLETE = "run_incomplete.json"
"""Present in a run folder while ``calnet run`` writes to it: a run that stopped early
(Ctrl-C, an error) leaves the files of two runs mixed there, and ``calnet predict`` and
``calnet verify`` refuse such a folder."""


def mark_incomplete(out: Path, stage: str) -> None:
    """Record in ``out`` that the run is at ``stage`` and not finished."""
    (Path(out) / INCOMPLETE).write_text(json.dumps({"stage": stage}) + "\n")


def mark_complete(out: Path) -> None:
    """Record in ``out`` that the run finished."""
    (Path(out) / INCOMPLETE).unlink(missing_ok=True)


def check_complete(run_dir: Path) -> None:
    """Raise :class:`CalnetError` when ``run_dir`` holds a run that did not finish."""
    path = Path(run_dir) / INCOMPLETE
    if path.is_file():
        try:
            stage = json.loads(path.read_text()).get("stage", "?")
        except (OSError, ValueError):
            stage = "?"
        raise CalnetError(f"the run in '{run_dir}' did not finish (it stopped in its {stage} "
                          "stage), so its files may mix two runs; run 'calnet run' with this "
                          "--out again to finish it")
