"""The code style and the package's layering are part of the suite, so that .ci/run checks them
with the tests: ruff (lint and format) and import-linter's contract in pyproject.toml."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool(name):
    path = Path(sys.executable).with_name(name)
    found = str(path) if path.exists() else shutil.which(name)
    if found is None:
        pytest.fail(f"{name} is not installed: pip install -e '.[test]'")
    return found


@pytest.mark.parametrize(
    "argv",
    [
        ["ruff", "check", "bayescap", "tests", "benchmarks", "data"],
        ["ruff", "format", "--check", "bayescap", "tests", "benchmarks", "data"],
        ["lint-imports"],
    ],
    ids=["ruff-check", "ruff-format", "import-linter"],
)
def test_tool_passes(argv):
    out = subprocess.run([_tool(argv[0]), *argv[1:]], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
