"""Is a folder writable? Asked before long work starts (a training run, an evaluation), so a read-only or full
file system is refused in one line up front instead of a traceback when the first file is written.

``check_writable_dir`` creates the folder (and missing parents) if needed, writes a small probe file, fsyncs it and
removes it; on failure it removes the folders it created, so nothing is left behind, and raises ``NotWritable`` (a
``ValueError``) whose message is one line naming the path and the reason.
"""
from __future__ import annotations

import errno
import os
import shutil
import uuid
from pathlib import Path

PROBE_BYTES = 64 * 1024


class NotWritable(ValueError):
    """A folder cannot be written: read-only, full, not a folder, no permission."""


def describe_os_error(error: OSError) -> str:
    """One line for a write failure: 'no space left on device', 'read-only file system', …"""
    if error.errno == errno.ENOSPC:
        return "no space left on device"
    text = error.strerror or str(error) or type(error).__name__
    return text.splitlines()[0].lower()


def check_writable_dir(folder: str | os.PathLike[str], what: str = "folder", probe_bytes: int = PROBE_BYTES) -> Path:
    """Create ``folder`` if missing and probe-write ``probe_bytes`` into it; ``NotWritable`` naming ``what``."""
    folder = Path(folder)
    created: list[Path] = []
    probe = folder / f".dynenv-probe-{uuid.uuid4().hex[:8]}"
    try:
        missing = []
        current = folder
        while not current.exists() and current != current.parent:
            missing.append(current)
            current = current.parent
        for path in reversed(missing):
            path.mkdir()
            created.append(path)
        if not folder.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "not a folder")
        with open(probe, "wb") as handle:
            handle.write(b"\0" * probe_bytes)
            handle.flush()
            os.fsync(handle.fileno())
        probe.unlink()
    except OSError as error:
        try:
            probe.unlink(missing_ok=True)
        except OSError:
            pass
        for path in reversed(created):
            try:
                path.rmdir()
            except OSError:
                pass
        raise NotWritable(f"{what} {folder} is not writable: {describe_os_error(error)}") from None
    return folder


def check_writable_file(path: str | os.PathLike[str], what: str = "file") -> None:
    """``path``'s folder must exist and take a new file; ``path`` itself must not be a folder."""
    path = Path(path)
    if path.is_dir():
        raise NotWritable(f"{what} {path}: it is a folder (give a file name)")
    if not path.parent.is_dir():
        raise NotWritable(f"{what} {path}: folder {path.parent} does not exist")
    check_writable_dir(path.parent, f"{what} {path}: folder", probe_bytes=4096)



def check_run_dir(folder: str | os.PathLike[str], needed_bytes: int, needs: str = "", what: str = "folder") -> Path:
    """``check_writable_dir``, then ``needed_bytes`` free on its file system: a read-only folder is refused as not
    writable, a disk too small for the run (it would fill part-way) as short of space; either way in one line, and
    no folder this made is left behind."""
    folder = Path(folder)
    missing = []
    current = folder.absolute()
    while not current.exists() and current != current.parent:
        missing.append(current)
        current = current.parent
    check_writable_dir(folder, what)
    try:
        check_free_space(folder, needed_bytes, what, needs)
    except NotWritable:
        for path in missing:                    # innermost first; they are empty: the probe removed its file
            try:
                path.rmdir()
            except OSError:
                pass
        raise
    return folder


def check_free_space(folder: str | os.PathLike[str], needed_bytes: int, what: str = "folder",
                     needs: str = "") -> None:
    """The file system that holds (or will hold) ``folder`` must have ``needed_bytes`` free: a run that would fill
    the disk part-way is refused up front, in one line."""
    current = Path(folder).absolute()
    while not current.exists() and current != current.parent:
        current = current.parent
    try:
        free = shutil.disk_usage(current).free
    except OSError as error:
        raise NotWritable(f"{what} {folder}: cannot read its free space: {describe_os_error(error)}") from None
    if free < needed_bytes:
        why = f" ({needs})" if needs else ""
        raise NotWritable(f"{what} {folder}: needs about {_megabytes(needed_bytes)}{why}, the disk has "
                          f"{_megabytes(free)} free")


def _megabytes(count: int) -> str:
    return f"{count / 2**20:.1f} MB"
