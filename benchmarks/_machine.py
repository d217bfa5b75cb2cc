"""One description of the machine for every benchmark's result file."""

import os
import platform

import numpy as np


def describe_machine() -> str:
    """CPU model, cores, and the versions that matter for timing."""
    cpu = platform.processor() or ""
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import emcee
    import scipy

    return (
        f"{cpu}, {os.cpu_count()} cores; Python {platform.python_version()}, numpy {np.__version__}, "
        f"scipy {scipy.__version__}, emcee {emcee.__version__}"
    )


def emit(lines, out=None) -> str:
    """Print a benchmark's Markdown lines and, with ``out``, write them there atomically (a
    temporary file in the same folder, then renamed: an interrupted run leaves the old result)."""
    import tempfile
    from pathlib import Path

    text = "\n".join(lines) + "\n"
    print(text)
    if out:
        out = Path(out)
        fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=out.name, suffix=".tmp")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(text)
            os.replace(tmp, out)
        except BaseException:
            os.unlink(tmp)
            raise
    return text
