"""Progress bars: tqdm on stderr when asked for, a silent stand-in otherwise.

Each bar counts up to a total fixed when it is made, so it never goes back; a step whose length
is only known later (another MCMC round) gets a bar of its own. The command line asks for bars
only when stderr is a terminal (``--progress``/``--no-progress`` override)."""

from __future__ import annotations


class _Silent:
    def update(self, n=1):
        pass

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def bar(enabled: bool, *, total: int | None, desc: str, unit: str = "it", leave: bool = False):
    """A tqdm bar on stderr (``enabled``) or a stand-in with the same ``update``/``close``."""
    if not enabled:
        return _Silent()
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, leave=leave)
