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

    return (f"{cpu}, {os.cpu_count()} cores; Python {platform.python_version()}, numpy {np.__version__}, "
            f"scipy {scipy.__version__}, emcee {emcee.__version__}")
