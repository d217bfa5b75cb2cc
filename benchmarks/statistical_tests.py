"""The suite's long statistical checks (pytest marker ``statistical``): coverage of the 95 %
intervals and the ranks of the truth (a small SBC) on 30 sensors drawn from the prior, the fast
path's gain intervals on 48 small ROIs against a reference, the coverage of the MTF's bootstrap
intervals on 40 synthetic edges, the standard preset's move mix on a skewed, bounded target (6 seeds),
emcee's DESnookerMove on a correlated Gaussian (a known defect: expected to fail), a slow burn-in
transient (sim00 from a poor start) found by the time-split R-hat and discarded, and single fits whose
95 % intervals must hold the truth: K of a 4 % compressive sensor on all rows and below 70 % of
saturation, the dark noise with the pixels' offsets spread across the rounding boundary, PRNU and DSNU
from one frame's spatial variance, and the extreme case of noise below 1 DN (a known failure that
passes or fails by chance). They take minutes, so the default ``pytest`` run leaves them out; this runs them
and writes ``benchmarks/results/statistical_tests.md`` (each test's outcome and time).

    python benchmarks/run.py statistical_tests
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "statistical_tests.md"


def main() -> int:
    from _machine import describe_machine, emit

    cmd = [
        sys.executable,
        "-m",
        "pytest",
        "-m",
        "statistical",
        "-n",
        "2",
        "-q",
        "-rA",
        "--durations=0",
        "-p",
        "no:cacheprovider",
    ]
    t0 = time.perf_counter()
    run = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    out = run.stdout
    outcome = {m.group(2): m.group(1) for m in re.finditer(r"^(PASSED|FAILED|ERROR|XFAIL|XPASS) (\S+)", out, re.M)}
    for m in re.finditer(r"^SKIPPED \[\d+\] (\S+?):\d+: (.*)$", out, re.M):  # "SKIPPED [1] file:line: reason"
        outcome[f"{m.group(1)} ({m.group(2)})"] = "SKIPPED"
    durations = {}
    for m in re.finditer(r"^\s*([0-9.]+)s (call|setup|teardown)\s+(\S+)", out, re.M):
        durations[m.group(3)] = durations.get(m.group(3), 0.0) + float(m.group(1))
    summary = next(
        (line for line in reversed(out.splitlines()) if " in " in line and ("passed" in line or "failed" in line)), ""
    )
    lines = [
        "# Statistical checks of the test suite",
        "",
        "`python benchmarks/run.py statistical_tests` (runs `python -m pytest -m statistical -n 2`; the default "
        "`pytest` run leaves these out to stay under 5 minutes). Machine: " + describe_machine() + ".",
        "",
        f"Result: {summary.strip('= ')} (wall {wall:.0f} s).",
        "",
        "| test | outcome | time s (setup + call) |",
        "| --- | --- | --- |",
    ]
    for name in sorted(set(outcome) | set(durations)):
        lines.append(f"| `{name}` | {outcome.get(name, '?')} | {durations.get(name, 0.0):.1f} |")
    emit(lines, OUT)
    return 0 if run.returncode == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
