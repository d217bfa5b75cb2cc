"""Command line: a thin layer over the Python API.

    bayescap fit sensor.csv|- [--json] [--seed N] [--out DIR] [--quality fast|standard|accurate]
                            [--fast-tolerance FRAC] [--fast-confidence P|none]   (--quality fast)

Bad input prints one line naming file, row and column, and exits with status 2.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from bayescap.cli.common import EXIT_BROKEN_PIPE, EXIT_INPUT
from bayescap.exceptions import InputError

__all__ = ["main", "build_parser", "COMMANDS"]

EXIT_STATUS_HELP = """exit status:
  0  done (without --strict also when a result is NOT CONVERGED: it says so)
  1  an output could not be written (the result was printed first), or a CSV of a batch failed
  2  bad input or usage: one line on standard error, nothing written
  3  --strict and a result not converged (the outputs are written first)
  130 interrupted; 141 standard output closed early (a pipe into 'head')"""


#: the commands, in the order of ``bayescap --help``
COMMANDS = ("fit", "ingest", "mtf", "compare", "report", "sweep", "datasheet", "colour", "summary")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser; with ``command`` (one of :data:`COMMANDS`) only that command's
    subparser, so that the other commands' modules (and what they import: frame readers, the sweep's
    optics, the colour fit) are not imported for it. Each command's own parser, help and errors
    are the same either way."""
    # each command's module is imported here, not at the top: `bayescap --version` imports none
    from bayescap._version import __version__

    def want(name):
        return command is None or command == name

    parser = argparse.ArgumentParser(
        prog="bayescap",
        description="Bayesian image-sensor characterization: photon-transfer data -> noise-model "
        "posterior -> image information capacity with credible intervals.",
    )
    parser.add_argument("--version", action="version", version=f"bayescap {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    if want("fit"):
        _add_fit(sub)
    if want("ingest"):
        from bayescap.cli.ingest import register as _register_ingest

        _register_ingest(sub)  # bayescap ingest (cli/ingest.py)
    if want("mtf"):
        _add_mtf(sub)
    if want("compare"):
        from bayescap.cli.compare import register as _register_compare

        _register_compare(sub)  # bayescap compare (cli/compare.py)
    if want("report"):
        from bayescap.cli.report import register as _register_report

        _register_report(sub, epilog=EXIT_STATUS_HELP)  # bayescap report (cli/report.py)
    if want("sweep"):
        from bayescap.cli.sweep import register as _register_sweep

        _register_sweep(sub)  # bayescap sweep (cli/sweep.py)
    if want("datasheet"):
        from bayescap.cli.datasheet import register as _register_datasheet

        _register_datasheet(sub, epilog=EXIT_STATUS_HELP)  # bayescap datasheet (cli/datasheet.py)
    if want("colour"):
        from bayescap.cli.colour import register as _register_colour

        _register_colour(sub, epilog=EXIT_STATUS_HELP)  # bayescap colour (cli/colour.py)
    if want("summary"):
        from bayescap.cli.summary import register as _register_summary

        _register_summary(sub)  # bayescap summary DIR (cli/summary.py)
    return parser


def _add_fit(sub):
    from bayescap.cli.common import (
        _add_metadata_overrides,
        add_fast_arguments,
        add_progress_arguments,
        add_strict_argument,
        seed_arg,
    )
    from bayescap.cli.fit import _cmd_fit

    p = sub.add_parser(
        "fit",
        help="fit a photon-transfer CSV and report capacity with intervals",
        description="Fit the Eq. 1 noise model to a photon-transfer CSV by MCMC and "
        "report every parameter, the derived figures and the information "
        "capacity with 68 % and 95 % credible intervals.",
        epilog=EXIT_STATUS_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "csv",
        nargs="+",
        help="photon-transfer CSV (format: README, 'Photon-transfer CSV'; '-' reads it from standard input); several "
        "CSVs are fitted as a batch (bayescap.batch.fit_many: the fast "
        "preset is vectorised across sensors); a folder stands for its *.csv files, in name order",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print the result as JSON (the contract's fit JSON; a JSON array of them for several CSVs)",
    )
    p.add_argument(
        "--jobs", type=int, default=1, metavar="N", help="several CSVs: worker processes for the batch (default 1)"
    )
    p.add_argument(
        "--seed",
        type=seed_arg,
        default=None,
        help="random seed: the same seed gives the same numbers (default: one is drawn, and "
        "recorded in the JSON and the report as 'seed N (drawn)')",
    )
    add_strict_argument(p)
    p.add_argument(
        "--out",
        metavar="DIR",
        help="also write result.json, report.txt, posterior.nc "
        "(ArviZ InferenceData), ptc.png and corner.png into DIR "
        "(several CSVs: DIR/<csv name>/result.json, each written as its chunk of sensors "
        "finishes; a rerun into the same DIR fits only what is not done: docs/batch.md)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        help="several CSVs with --out: run the batch on the Dask cluster whose scheduler is at "
        "ADDRESS (e.g. tcp://10.0.0.5:8786; pip install 'bayescap[dask]')",
    )
    p.add_argument(
        "--dask",
        type=int,
        metavar="N_WORKERS",
        default=None,
        help="several CSVs with --out: run the batch on a new local Dask cluster of N_WORKERS processes",
    )
    p.add_argument(
        "--quality",
        choices=("fast", "standard", "accurate"),
        default="standard",
        help="speed/accuracy preset (README, 'Performance'; docs/performance.md, 'Presets and "
        "knobs'); default standard",
    )
    add_fast_arguments(p)
    p.add_argument(
        "--scene",
        default=None,
        metavar="KEY=VALUE,...",
        help="evaluate TR and capacity for a scene: exposure_s=<s>, temperature_c=<°C> "
        "(dark current doubles every 6 °C from the CSV's temperature_c); e.g. "
        "--scene exposure_s=0.1,temperature_c=45",
    )
    p.add_argument(
        "--scene-exposure-s",
        type=float,
        default=None,
        help="exposure time (s) at which TR and capacity are evaluated "
        "(default: median exposure time of the unclipped rows)",
    )
    p.add_argument(
        "--temperature-c",
        type=float,
        default=None,
        help="sensor temperature of the scene (°C); needs the measurement's temperature_c",
    )
    p.add_argument(
        "--mtf",
        metavar="FILE",
        default=None,
        help="measured system MTF for Δs: a CSV table (freq_cy_per_px,mtf) or a slanted-edge "
        "image (ISO 12233, with bootstrap draws so capacity carries sharpness uncertainty); "
        "default: ideal pixel aperture x diffraction-limited lens from the metadata",
    )
    p.add_argument(
        "--select-model",
        action="store_true",
        help="fit the nested likelihood variants (plain χ², + discrepancy, + outlier mixture) "
        "and keep the one PSIS-LOO prefers (README, 'Model selection')",
    )
    add_progress_arguments(p)
    _add_metadata_overrides(p)
    p.set_defaults(func=_cmd_fit)


def _add_mtf(sub):
    from bayescap.cli.common import seed_arg
    from bayescap.cli.mtf import _cmd_mtf, add_lens_arguments

    p = sub.add_parser(
        "mtf",
        help="slanted-edge MTF (ISO 12233:2023) with bootstrap intervals",
        description="Measure the MTF of a slanted edge following ISO 12233:2023 (Burns' "
        "sfrmat5 steps), with bootstrap draws over phase cycles of rows "
        "(docs/mtf.md).",
    )
    p.add_argument("image", help="edge image: TIFF, PNG, JPEG or .npy (linear data)")
    p.add_argument("--roi", default=None, help="x0,y0,x1,y1 in pixels (end-exclusive); default whole image")
    p.add_argument("--npol", type=int, choices=range(1, 6), default=5, help="edge polynomial order (default 5)")
    p.add_argument("--channel", default=None, help="R, G, B, lum (RGB images; default lum) or mono")
    p.add_argument("--window", choices=("tukey", "hamming"), default="tukey")
    p.add_argument("--n-boot", type=int, default=200, help="bootstrap draws (default 200)")
    p.add_argument("--seed", type=seed_arg, default=0)
    p.add_argument(
        "--correct-bin-width",
        action="store_true",
        help="divide out the 1/4-pixel binning (recommended for Δs; off = ISO output)",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--out", metavar="FILE.csv", help="write freq_cy_per_px,mtf,mtf_ci95_low,mtf_ci95_high")
    add_lens_arguments(p)
    p.set_defaults(func=_cmd_mtf)


def main(argv=None) -> int:
    if list(sys.argv[1:] if argv is None else argv) == ["--version"]:  # without building the parser
        from bayescap._version import __version__

        print(f"bayescap {__version__}")
        return 0
    from bayescap._heap import retain_freed_memory

    retain_freed_memory()  # this process is ours: keep freed temporaries for the next log_prob call
    warnings.filterwarnings("ignore", category=FutureWarning)  # ArviZ's refactor notice
    warnings.filterwarnings("ignore", module="arviz")
    from bayescap.exceptions import ConvergenceWarning

    warnings.filterwarnings("ignore", category=ConvergenceWarning)  # reported in the output instead
    words = list(sys.argv[1:] if argv is None else argv)
    # the first word not an option is the command (the top level has no option taking a value)
    command = next((w for w in words if not w.startswith("-")), None)
    parser = build_parser(command if command in COMMANDS else None)
    args = parser.parse_args(argv)
    try:
        status = int(args.func(args) or 0)
        sys.stdout.flush()  # here, so that a closed pipe is caught below
        return status
    except BrokenPipeError:
        # the reader went away (`bayescap ... | head -1`): no traceback; stdout goes to devnull so
        # the interpreter's last flush does not fail again (the Python docs' recipe, signal module)
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except InputError as e:
        print(f"bayescap: error: {e}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("bayescap: interrupted", file=sys.stderr)
        return 130
