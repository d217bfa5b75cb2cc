"""Keep freed large arrays in the process heap (glibc), instead of handing them back to the
operating system after every ``log_prob`` call.

A ``log_prob`` call on a few thousand draws creates tens of temporary (draws, rows) arrays of
0.1–3 MB. With glibc's default settings, freed memory at the top of the heap is returned to the
kernel once more than 2× the dynamic mmap threshold is free, so the next call faults the same
pages back in (transparent huge pages: 2 MB zeroed per fault). That costs a few per cent of a
batch fit and up to a third of a repeated 6 000-draw ``log_prob`` call.

:func:`retain_freed_memory` raises the two thresholds once (``mallopt``): arrays up to 32 MB
come from the heap, and free heap is returned to the kernel only above 256 MB. The memory kept
is bounded by the process's own peak use. Importing :mod:`bayescap` does not call it: the
command line does, at start, and a program may (``bayescap.retain_freed_memory()``). It acts:

- only on glibc (Linux); elsewhere it does nothing;
- not when the environment already tunes malloc (``MALLOC_TRIM_THRESHOLD_``,
  ``MALLOC_MMAP_THRESHOLD_`` or ``GLIBC_TUNABLES`` naming ``glibc.malloc``);
- not when ``BAYESCAP_NO_MALLOPT=1``.

Setting any of these parameters turns off glibc's dynamic adjustment of the mmap threshold
for the whole process (``man 3 mallopt``); that is the purpose here."""

from __future__ import annotations

import os
import sys

#: ``mallopt`` parameter numbers (glibc ``malloc.h``)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024  # glibc's largest allowed value on 64-bit
TRIM_THRESHOLD_BYTES = 256 * 1024 * 1024

_state: dict = {}


def _env_tunes_malloc(env) -> bool:
    if env.get("BAYESCAP_NO_MALLOPT", "") not in ("", "0"):
        return True
    if "MALLOC_TRIM_THRESHOLD_" in env or "MALLOC_MMAP_THRESHOLD_" in env:
        return True
    return "glibc.malloc" in env.get("GLIBC_TUNABLES", "")


def _libc(ctypes):
    """The C library: glibc by its soname, else whatever ``ctypes.util.find_library`` finds (which
    runs ``ldconfig``, ~10 ms, and imports ``subprocess``: only where the soname is not glibc's)."""
    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:
        import ctypes.util

        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")


def retain_freed_memory() -> dict:
    """Raise glibc's trim and mmap thresholds once per process (see the module docstring).

    Returns ``{"applied": bool, "reason": str}`` (also kept for :func:`status`)."""
    if _state:
        return dict(_state)
    if not sys.platform.startswith("linux"):
        _state.update(applied=False, reason=f"not glibc ({sys.platform})")
    elif _env_tunes_malloc(os.environ):
        _state.update(
            applied=False, reason="left to the environment (BAYESCAP_NO_MALLOPT, MALLOC_*_ or GLIBC_TUNABLES)"
        )
    else:
        import ctypes  # here, not at the top: `import bayescap` stays without ctypes (and subprocess)

        try:
            libc = _libc(ctypes)
            mallopt = libc.mallopt
        except (OSError, AttributeError):
            _state.update(applied=False, reason="no mallopt in the C library (not glibc)")
        else:
            mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
            mallopt.restype = ctypes.c_int
            ok = (
                mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
                and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1
            )
            _state.update(applied=bool(ok), reason="mallopt" if ok else "mallopt refused the values")
    return dict(_state)


def status() -> dict:
    """What :func:`retain_freed_memory` did in this process (empty if it was not called)."""
    return dict(_state)
