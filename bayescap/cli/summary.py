"""``bayescap summary DIR``: rebuild a batch folder's ``summary.csv`` (and ``summary.parquet``) from
its ``<name>/result.json`` files (:mod:`bayescap.batch.summary`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def run_summary(args) -> int:
    from bayescap.batch.store import RESULT_FILE
    from bayescap.batch.summary import write_summary
    from bayescap.cli.common import EXIT_FAILURE, EXIT_INPUT, say

    out = Path(args.dir)
    if not out.is_dir():
        print(f"bayescap: error: {out}: not a directory (a batch's --out DIR)", file=sys.stderr)
        return EXIT_INPUT
    if not any(out.glob(f"*/{RESULT_FILE}")):
        print(f"bayescap: error: {out}: no <name>/{RESULT_FILE} in it (a batch's --out DIR)", file=sys.stderr)
        return EXIT_INPUT
    try:
        written = write_summary(out)
    except ValueError as e:  # a result.json that is not JSON
        print(f"bayescap: error: {out}: a {RESULT_FILE} is not readable JSON ({e})", file=sys.stderr)
        return EXIT_INPUT
    except OSError as e:
        print(f"bayescap: error: cannot write into {out} ({e.strerror or e}); nothing was written", file=sys.stderr)
        return EXIT_FAILURE
    say(args, "wrote " + " and ".join(map(str, written)) + " (pandas.read_csv reads the CSV)")
    return 0


def register(sub) -> None:
    """Add ``summary`` to the command line's subcommands ``sub``."""
    p = sub.add_parser(
        "summary",
        help="rebuild a batch folder's summary.csv (one row per sensor) from its result.json files",
        description="Write DIR/summary.csv (and DIR/summary.parquet with pyarrow): one row per "
        "DIR/<name>/result.json, one column per median and interval end, converged, flags "
        "(docs/batch.md).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("dir", metavar="DIR", help="the --out folder of a batch")
    p.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    p.set_defaults(func=run_summary)
