"""``bayescap ingest``: frames (RAW/DNG/TIFF/PNG/npy) to a photon-transfer CSV."""

from __future__ import annotations

import argparse
import sys

from bayescap.exceptions import IngestError
from bayescap.io import CHANNELS, ingest


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------
def add_ingest_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the options of ``bayescap ingest`` to ``parser`` (and return it)."""
    parser.add_argument(
        "source",
        help="manifest CSV, EMVA 1288 descriptor (*.txt), or a directory holding manifest.csv or one descriptor",
    )
    parser.add_argument(
        "-o",
        "--out",
        required=True,
        help="photon-transfer CSV to write (with --channel all: one file per "
        "channel, _R/_Gr/_Gb/_B added before the suffix)",
    )
    parser.add_argument(
        "--roi",
        default=None,
        help="region of interest: x0,y0,x1,y1 in pixels (x1, y1 exclusive) or "
        "a centred fraction of each dimension (default 0.5)",
    )
    parser.add_argument(
        "--channel",
        choices=CHANNELS,
        default="G",
        help="Bayer channel; G pools Gr and Gb, all writes four files (ignored for monochrome sensors; default G)",
    )
    parser.add_argument(
        "--format",
        dest="format",
        choices=("auto", "manifest", "emva"),
        default="auto",
        help="how to read SOURCE (default auto)",
    )
    return parser


def run_ingest(args: argparse.Namespace) -> int:
    """Run ``bayescap ingest``: 0 on success (paths printed), 2 on an input error (one line on
    standard error, nothing written)."""
    notices: list = []
    try:
        paths = ingest(
            args.source,
            out=args.out,
            roi=args.roi,
            channel=args.channel,
            fmt=args.format,
            progress=sys.stderr.isatty(),
            notices=notices,
        )
    except IngestError as exc:
        print(f"bayescap ingest: error: {exc}", file=sys.stderr)
        return 2
    for kind, text in notices:  # what was assumed, and what looks implausible in the table
        print(f"bayescap ingest: {kind}: {text}", file=sys.stderr)
    for p in paths:
        print(p)
    return 0


def register(sub) -> None:
    """Add ``bayescap ingest`` to the sub-command parsers ``sub``."""
    p = sub.add_parser(
        "ingest",
        help="frames (RAW/DNG/TIFF/PNG/npy) -> photon-transfer CSV",
        description="Compute a photon-transfer CSV from flat-field and dark frames "
        "described by a manifest CSV or an EMVA 1288 descriptor "
        "(docs/ingest.md).",
    )
    add_ingest_arguments(p)
    p.set_defaults(func=run_ingest)
