"""Progress for long runs: a tqdm bar on a terminal, a line every 10% otherwise (logs, CI)."""
from __future__ import annotations

import sys
from collections.abc import Callable

from tqdm import tqdm


def progress_bar(desc: str, total: int, enabled: bool = True) -> tuple[Callable[[int, int], None],
                                                                       Callable[[], None]]:
    """Return ``(update(done, total), close())``."""
    if not enabled:
        return (lambda done, total: None), (lambda: None)
    if sys.stderr.isatty():
        bar = tqdm(total=total, desc=desc, unit="frame", leave=False)

        def update(done: int, _total: int) -> None:
            bar.update(done - bar.n)

        return update, bar.close
    state = {"next": 0}

    def update_plain(done: int, total_: int) -> None:
        pct = 100 * done // max(total_, 1)
        if pct >= state["next"]:
            print(f"{desc}: {done}/{total_} ({pct}%)", file=sys.stderr, flush=True)
            state["next"] = pct + 10

    return update_plain, (lambda: None)
