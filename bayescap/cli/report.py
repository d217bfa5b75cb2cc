"""``bayescap report``: a self-contained HTML report of one or more sensors."""

from __future__ import annotations

import argparse
import sys
import warnings

from bayescap.exceptions import CompareInputError


def add_report_arguments(p: argparse.ArgumentParser) -> None:
    from bayescap.cli.colour import add_colour_result_argument
    from bayescap.cli.common import add_comparison_arguments, add_strict_argument

    p.add_argument("csv", nargs="+", help="photon-transfer CSVs, one per sensor")
    p.add_argument("-o", "--output", default="report.html", help="HTML file to write (default report.html)")
    add_comparison_arguments(p)
    p.add_argument("--title", default="bayescap sensor comparison")
    add_strict_argument(p)
    add_colour_result_argument(p)


def run_report(args) -> int:
    """``bayescap report``: returns the exit status (2 with one line on bad input)."""
    from bayescap._progress import bar
    from bayescap.cli.colour import colour_result_from_args
    from bayescap.cli.common import fast_settings_from_args, progress_enabled, say, strict_status
    from bayescap.exceptions import ConvergenceWarning, InputError, PTCInputError
    from bayescap.report.html import write_report
    from bayescap.studies.compare import (
        compare,
    )

    try:
        fs = fast_settings_from_args(args)
        colour = colour_result_from_args(args)
    except InputError as e:
        print(f"bayescap: error: {e}", file=sys.stderr)
        return 2
    from bayescap.io.atomic import output_problem

    problem = output_problem(args.output, args.csv, option="-o")  # before any fitting
    if problem:
        print(f"bayescap: error: {problem}", file=sys.stderr)
        return 2
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=ConvergenceWarning)
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
    except (PTCInputError, CompareInputError, OSError) as e:
        print(f"bayescap: error: {e}", file=sys.stderr)
        return 2
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=FutureWarning)
            with bar(progress_enabled(args), total=1, desc="report: plots and HTML", unit="page") as step:
                out = write_report(cmp, args.output, title=args.title, colour=colour)
                step.update()
    except OSError as e:
        print(f"bayescap: error: cannot write {args.output} ({e.strerror or e}); nothing was written", file=sys.stderr)
        return 1
    say(args, f"wrote {out}")
    return strict_status(args, [sc.result for sc in cmp.sensors])


def register(sub, epilog=None) -> None:
    """Add ``bayescap report`` to the sub-command parsers ``sub``."""
    p = sub.add_parser(
        "report",
        help="self-contained HTML report of one or more sensors",
        description="Fit the sensors and write one self-contained HTML page (docs/compare.md).",
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_report_arguments(p)
    p.set_defaults(func=run_report)
