"""Atomic file writes: an output is either the old file or the whole new one, never half."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable, IO

from .errors import JackboxError


def write_atomic(path: str | Path, data: str | bytes | Callable[[IO[bytes]], None]) -> Path:
    """Write `data` (text, bytes, or a function that writes to a binary file) to `path`.

    The data goes to a temporary file in the same folder, which then replaces
    `path` in one rename; on any error the temporary file is removed and an
    existing `path` is left as it was.
    """
    if not isinstance(path, (str, Path)) or not str(path):
        raise JackboxError(f"{path!r}: not a file name to write to")
    path = Path(path)
    if path.is_dir():
        raise JackboxError(f"{path}: is a folder, not a file to write")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise JackboxError(f"{path}: its folder {path.parent} cannot be made (a file is in the way)") from None
    remove_stale_temporaries(path.parent)
    umask = os.umask(0)
    os.umask(umask)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=TMP_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as fh:
            if callable(data):
                data(fh)
            else:
                fh.write(data.encode("utf-8") if isinstance(data, str) else data)
        os.chmod(tmp, 0o666 & ~umask)   # mkstemp makes 0600; outputs are ordinary files
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


TMP_SUFFIX = ".jackbox-tmp"


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Remove the temporary files that a killed writer (SIGKILL: no chance to clean up)
    left in `folder`: those whose process no longer runs. Returns what was removed."""
    removed = []
    for tmp in folder.glob(f".*{TMP_SUFFIX}"):
        try:
            pid = int(tmp.name[: -len(TMP_SUFFIX)].split(".")[-2])
        except (ValueError, IndexError):
            continue
        if pid != os.getpid() and not _alive(pid):
            try:
                tmp.unlink()
                removed.append(tmp)
            except OSError:
                pass
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True       # someone else's process
    return True


def check_writable(path: Path) -> None:
    """Refuse, before any work, an ``--out`` that cannot be written: the nearest
    existing folder on its path must be a writable folder."""
    existing = Path(path).absolute()
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise JackboxError(f"--out {path}: {existing} is a file, not a folder")
    try:     # (a permission check alone says yes to root on a read-only mount or in /proc)
        tempfile.TemporaryFile(dir=existing).close()
    except OSError as exc:
        raise JackboxError(f"--out {path}: {existing} cannot be written ({exc.strerror or exc})") from None
