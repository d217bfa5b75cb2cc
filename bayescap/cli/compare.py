"""``bayescap compare``: fit each sensor and compare capacities."""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from bayescap.exceptions import CompareInputError


def add_compare_arguments(p: argparse.ArgumentParser) -> None:
    from bayescap.cli.common import add_comparison_arguments

    p.add_argument("csv", nargs="+", help="photon-transfer CSVs, one per sensor")
    add_comparison_arguments(p)
    p.add_argument("--json", action="store_true", help="print the comparison as JSON")
    p.add_argument("--out", metavar="DIR", help="also write compare.json and compare.txt into DIR")


def run_compare(args) -> int:
    """``bayescap compare``: returns the exit status (2 with one line on bad input)."""
    from bayescap.cli.common import fast_settings_from_args, progress_enabled
    from bayescap.exceptions import ConvergenceWarning, InputError, PTCInputError
    from bayescap.io.atomic import write_files_atomically
    from bayescap.studies.compare import (
        compare,
        format_compare_text,
    )

    try:
        fs = fast_settings_from_args(args)
    except InputError as e:
        print(f"bayescap: error: {e}", file=sys.stderr)
        return 2
    if args.out:  # before any fitting
        from bayescap.io.atomic import output_problem

        problem = output_problem(args.out, args.csv, directory=True) or next(
            (output_problem(Path(args.out) / n, args.csv) for n in ("compare.json", "compare.txt")), None
        )
        if problem:
            print(f"bayescap: error: {problem}", file=sys.stderr)
            return 2
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=ConvergenceWarning)  # reported in the output
            warnings.filterwarnings("ignore", category=FutureWarning)
            cmp = compare(
                args.csv,
                area=args.area,
                h0_lux_s=args.h0,
                mid_grey=args.mid_grey,
                seed=args.seed,
                quality=args.quality,
                progress=progress_enabled(args),
                fit_kwargs=None if fs is None else {"fast_settings": fs},
                practical_difference=args.practical_difference,
            )
    except (PTCInputError, CompareInputError) as e:
        print(f"bayescap: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"bayescap: error: {e}", file=sys.stderr)
        return 2
    js = cmp.to_json()
    text = format_compare_text(json.loads(js))
    sys.stdout.write(js if args.json else text)  # first: a write error below does not lose it
    sys.stdout.flush()
    if args.out:
        out = Path(args.out)
        try:
            write_files_atomically({out / "compare.json": js, out / "compare.txt": text})
        except OSError as e:
            print(f"bayescap: error: cannot write into {out} ({e.strerror or e}); nothing was written", file=sys.stderr)
            return 1
    return 0


def register(sub) -> None:
    """Add ``bayescap compare`` to the sub-command parsers ``sub``."""
    p = sub.add_parser(
        "compare",
        help="compare sensors: capacity at full resolution and fixed area, TR at H0, pairwise P(C_A > C_B)",
        description="Fit each sensor and compare capacities with credible intervals and "
        "pairwise probabilities (docs/compare.md).",
    )
    add_compare_arguments(p)
    p.set_defaults(func=run_compare)
