"""bayescap._heap: glibc keeps freed temporaries in the heap (issue 7, speed), unless the user
tunes malloc themselves or opts out."""
import sys

import pytest

from bayescap import _heap


@pytest.mark.parametrize("env, left_alone", [
    ({}, False),
    ({"BAYESCAP_NO_MALLOPT": "1"}, True),
    ({"BAYESCAP_NO_MALLOPT": "0"}, False),
    ({"MALLOC_TRIM_THRESHOLD_": "1000000"}, True),
    ({"MALLOC_MMAP_THRESHOLD_": "1000000"}, True),
    ({"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=1000000"}, True),
    ({"GLIBC_TUNABLES": "glibc.pthread.rseq=0"}, False),
])
def test_environment_decides_whether_malloc_is_tuned(env, left_alone):
    assert _heap._env_tunes_malloc(env) is left_alone


def test_applied_once_at_import_and_reported():
    import os

    st = _heap.status()
    assert set(st) == {"applied", "reason"}         # import bayescap called it
    assert _heap.retain_freed_memory() == st        # idempotent
    if sys.platform.startswith("linux") and not _heap._env_tunes_malloc(os.environ):
        assert st["applied"] is True, st["reason"]
    else:
        assert st["applied"] is False
