"""The one progress bar of long work (tqdm on stderr): shown only when asked, only on a
terminal (a log file or a pipe gets none) unless ``JACKBOX_PROGRESS=1`` asks for it
anyway, and after 0.5 s."""

from __future__ import annotations

import os
import sys
from typing import Any


class _Off:
    """A bar that shows nothing (progress not asked for, or no terminal to show it on)."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def wanted(enabled: bool) -> bool:
    """Whether a bar asked for (`enabled`) is shown: on a terminal, or when the environment asks."""
    if not enabled:
        return False
    forced = os.environ.get("JACKBOX_PROGRESS", "").strip().lower()
    if forced in ("1", "true", "yes", "always"):
        return True
    if forced in ("0", "false", "no", "never"):
        return False
    return sys.stderr.isatty()


def progress_bar(total: int, enabled: bool, unit: str, desc: str | None = None) -> Any:
    """A tqdm bar counting `unit`s up to `total`, or a silent stand-in when it is not shown."""
    if not wanted(enabled):
        return _Off()
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, desc=desc, unit_scale=True, delay=0.5, leave=False)
