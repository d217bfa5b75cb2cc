"""``bayescap datasheet``: fit one photon-transfer CSV and write its one-page EMVA 1288 datasheet
(HTML; docs/emva1288.md)."""

from __future__ import annotations

import argparse
import json
import sys


def add_datasheet_arguments(p: argparse.ArgumentParser) -> None:
    from bayescap.cli.common import _add_metadata_overrides, add_fast_arguments, add_strict_argument, seed_arg

    p.add_argument("csv", help="photon-transfer CSV (with photons_per_pixel for η, μp.min, μp.sat and LE)")
    p.add_argument("-o", "--output", default="datasheet.html", help="HTML file to write (default datasheet.html)")
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
    add_strict_argument(p)
    _add_metadata_overrides(p)


def run_datasheet(args) -> int:
    """``bayescap datasheet``: returns the exit status (2 with one line on bad input)."""
    from bayescap.api import fit, load
    from bayescap.cli.common import _OVERRIDE_KEYS, fast_settings_from_args, strict_status
    from bayescap.exceptions import InputError, PTCInputError
    from bayescap.io.atomic import atomic_write_text
    from bayescap.posterior.emva import emva1288_view
    from bayescap.report.datasheet import datasheet_html

    overrides = {k: getattr(args, k) for k in _OVERRIDE_KEYS if getattr(args, k, None) is not None}
    try:
        fs = fast_settings_from_args(args)
        data = load(args.csv, **overrides)
        kw = {} if fs is None else {"fast_settings": fs}
        result = fit(data, seed=args.seed, quality=args.quality, **kw)
        view = emva1288_view(result)
        atomic_write_text(args.output, datasheet_html(result, view=view, title=args.title))
        if args.json:
            atomic_write_text(args.json, json.dumps(view, indent=2) + "\n")
    except (PTCInputError, InputError, OSError) as e:
        print(f"bayescap: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.output}" + (f" and {args.json}" if args.json else ""))
    return strict_status(args, [result])


def register(sub, epilog=None) -> None:
    """Add ``datasheet`` to the command line's subcommands ``sub`` (``epilog``: the exit statuses)."""
    p = sub.add_parser(
        "datasheet",
        help="one-page EMVA 1288 datasheet (HTML) of a fit, with credible intervals",
        description="Fit a photon-transfer CSV and write the EMVA 1288 Release 4.0 quantities with 95 %% "
        "credible intervals, the standard's recipe beside them, the PTC and SNR plots (docs/emva1288.md).",
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_datasheet_arguments(p)
    p.set_defaults(func=run_datasheet)
