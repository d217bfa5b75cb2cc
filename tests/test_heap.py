"""bayescap._heap: glibc keeps freed temporaries in the heap (speed), unless the user
tunes malloc themselves or opts out."""

import sys

import pytest

from bayescap import _heap


@pytest.mark.parametrize(
    "env, left_alone",
    [
        ({}, False),
        ({"BAYESCAP_NO_MALLOPT": "1"}, True),
        ({"BAYESCAP_NO_MALLOPT": "0"}, False),
        ({"MALLOC_TRIM_THRESHOLD_": "1000000"}, True),
        ({"MALLOC_MMAP_THRESHOLD_": "1000000"}, True),
        ({"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=1000000"}, True),
        ({"GLIBC_TUNABLES": "glibc.pthread.rseq=0"}, False),
    ],
)
def test_environment_decides_whether_malloc_is_tuned(env, left_alone):
    assert _heap._env_tunes_malloc(env) is left_alone


def _status_after(code):
    import subprocess

    out = subprocess.run(
        [sys.executable, "-c", code + "\nfrom bayescap import _heap\nprint(_heap.status())"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    return eval(out.stdout.strip().splitlines()[-1])


def test_import_changes_nothing_global():
    """A library has no side effects: importing bayescap leaves malloc as it was."""
    assert _status_after("import bayescap") == {}


def test_the_command_line_applies_it_once_and_reports():
    import os

    st = _status_after(
        "import bayescap.cli\ntry:\n    bayescap.cli.main(['fit', '--help'])\nexcept SystemExit:\n    pass"
    )
    assert set(st) == {"applied", "reason"}
    if sys.platform.startswith("linux") and not _heap._env_tunes_malloc(os.environ):
        assert st["applied"] is True, st["reason"]
    else:
        assert st["applied"] is False
    assert _heap.retain_freed_memory() == _heap.retain_freed_memory()  # idempotent
