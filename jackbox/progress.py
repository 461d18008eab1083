"""The one progress bar of long work (tqdm on stderr): shown only when asked, and after 0.5 s."""

from __future__ import annotations

from typing import Any


class _Off:
    """A bar that shows nothing (progress not asked for)."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def progress_bar(total: int, enabled: bool, unit: str, desc: str | None = None) -> Any:
    """A tqdm bar counting `unit`s up to `total`, or a silent stand-in when not enabled."""
    if not enabled:
        return _Off()
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, desc=desc, unit_scale=True, delay=0.5, leave=False)
