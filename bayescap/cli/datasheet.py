"""``bayescap datasheet``: fit one photon-transfer CSV and write its one-page EMVA 1288 datasheet
(HTML, and/or a one-page PDF; docs/emva1288.md)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path


def add_datasheet_arguments(p: argparse.ArgumentParser) -> None:
    from bayescap.cli.colour import add_colour_result_argument
    from bayescap.cli.common import (
        _add_metadata_overrides,
        add_fast_arguments,
        add_progress_arguments,
        add_strict_argument,
        seed_arg,
    )

    p.add_argument("csv", help="photon-transfer CSV (with photons_per_pixel for η, μp.min, μp.sat and LE)")
    p.add_argument(
        "-o",
        "--output",
        default="datasheet.html",
        help="file to write (default datasheet.html); a name ending .pdf writes the one-page PDF instead of HTML",
    )
    p.add_argument(
        "--pdf",
        nargs="?",
        const=True,
        default=None,
        metavar="FILE",
        help="also write the datasheet as a one-page PDF (A4 landscape) to FILE (default: the output's name with .pdf)",
    )
    p.add_argument("--seed", type=seed_arg, default=None, help="random seed: the same seed gives the same numbers")
    p.add_argument(
        "--quality",
        choices=("fast", "standard", "accurate"),
        default="standard",
        help="speed/accuracy preset (default standard)",
    )
    p.add_argument("--title", default=None, help="heading (default: the CSV's '# sensor:' name)")
    p.add_argument(
        "--json",
        metavar="FILE",
        default=None,
        help="also write the EMVA 1288 view (bayescap.posterior.emva.emva1288_view) as JSON",
    )
    add_fast_arguments(p)
    add_progress_arguments(p)
    add_strict_argument(p)
    _add_metadata_overrides(p)
    add_colour_result_argument(p)


def run_datasheet(args) -> int:
    """``bayescap datasheet``: returns the exit status (2 with one line on bad input)."""
    from bayescap._progress import bar
    from bayescap.api import fit, load
    from bayescap.cli.colour import colour_result_from_args
    from bayescap.cli.common import _OVERRIDE_KEYS, fast_settings_from_args, progress_enabled, say, strict_status
    from bayescap.exceptions import InputError, PTCInputError
    from bayescap.io.atomic import atomic_write_text, output_problem
    from bayescap.posterior.emva import emva1288_view
    from bayescap.report.datasheet import datasheet_html
    from bayescap.report.datasheet_pdf import write_datasheet_pdf

    out = Path(args.output)
    pdf = out.with_suffix(".pdf") if args.pdf is True else (Path(args.pdf) if args.pdf else None)
    html_out = None if out.suffix.lower() == ".pdf" else out
    pdf = out if html_out is None else pdf
    targets = [(html_out, "-o"), (pdf, "--pdf" if html_out is not None else "-o"), (args.json, "--json")]
    given = [(Path(t), o) for t, o in targets if t]
    for k, (t, o) in enumerate(given):  # two outputs on one file: one would replace the other
        for t2, o2 in given[:k]:
            if os.path.abspath(t) == os.path.abspath(t2):
                print(
                    f"bayescap: error: {o} {t} is also the {o2} output: give each output its own file", file=sys.stderr
                )
                return 2
    for target, option in targets:  # before any fitting
        problem = target and output_problem(target, [args.csv], option=option)
        if problem:
            print(f"bayescap: error: {problem}", file=sys.stderr)
            return 2
    overrides = {k: getattr(args, k) for k in _OVERRIDE_KEYS if getattr(args, k, None) is not None}
    try:
        fs = fast_settings_from_args(args)
        colour = colour_result_from_args(args)  # bayescap colour's result, for a colour section
        data = load(args.csv, **overrides)
        kw = {} if fs is None else {"fast_settings": fs}
        result = fit(data, seed=args.seed, quality=args.quality, progress=progress_enabled(args), **kw)
    except (PTCInputError, InputError, OSError) as e:
        print(f"bayescap: error: {e}", file=sys.stderr)
        return 2
    n_steps = 1 + sum(x is not None and x is not False for x in (html_out, pdf, args.json))
    written = []
    try:
        with bar(progress_enabled(args), total=n_steps, desc="datasheet: EMVA 1288 view, pages", unit="step") as steps:
            view = emva1288_view(result)
            steps.update()
            if html_out is not None:
                atomic_write_text(html_out, datasheet_html(result, view=view, title=args.title, colour=colour))
                written.append(str(html_out))
                steps.update()
            if pdf is not None:
                write_datasheet_pdf(result, pdf, view=view, title=args.title, colour=colour)
                written.append(str(pdf))
                steps.update()
            if args.json:
                atomic_write_text(args.json, json.dumps(view, indent=2) + "\n")
                written.append(str(args.json))
                steps.update()
    except OSError as e:
        done = f" ({', '.join(written)} written)" if written else ""
        print(f"bayescap: error: cannot write {e.filename or 'an output'} ({e.strerror or e}){done}", file=sys.stderr)
        return 1
    say(args, "wrote " + " and ".join(written))
    return strict_status(args, [result])


def register(sub, epilog=None) -> None:
    """Add ``datasheet`` to the command line's subcommands ``sub`` (``epilog``: the exit statuses)."""
    p = sub.add_parser(
        "datasheet",
        help="one-page EMVA 1288 datasheet (HTML, or PDF) of a fit, with credible intervals",
        description="Fit a photon-transfer CSV and write the EMVA 1288 Release 4.0 quantities with 95 % "
        "credible intervals, the standard's recipe beside them, the PTC and SNR plots (docs/emva1288.md).",
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_datasheet_arguments(p)
    p.set_defaults(func=run_datasheet)
