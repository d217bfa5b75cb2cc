"""Command line: a thin layer over the Python API.

    bayescap fit sensor.csv [--json] [--seed N] [--out DIR] [--quality fast|standard|accurate]

Bad input prints one line naming file, row and column, and exits with status 2.
"""
from __future__ import annotations

import argparse
import sys
import warnings

__all__ = ["main", "build_parser"]

EXIT_INPUT = 2


class InputError(Exception):
    """Any refusal of user input: printed on one line, exit status 2."""


def _add_metadata_overrides(p):
    g = p.add_argument_group("sensor metadata (override the CSV's '# key: value' lines)")
    g.add_argument("--pixel-pitch-um", type=float, dest="pixel_pitch_um")
    g.add_argument("--width-px", type=int, dest="width_px")
    g.add_argument("--height-px", type=int, dest="height_px")
    g.add_argument("--adc-bits", type=int, dest="adc_bits")
    g.add_argument("--f-number", type=float, dest="f_number")
    g.add_argument("--wavelength-nm", type=float, dest="wavelength_nm")
    g.add_argument("--fill-factor", type=float, dest="fill_factor")
    g.add_argument("--sensor-name", dest="sensor")


_OVERRIDE_KEYS = ("pixel_pitch_um", "width_px", "height_px", "adc_bits", "f_number", "wavelength_nm",
                  "fill_factor", "sensor")


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="bayescap",
        description="Bayesian image-sensor characterization: photon-transfer data -> noise-model "
                    "posterior -> image information capacity with credible intervals.")
    parser.add_argument("--version", action="version", version=f"bayescap {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("fit", help="fit a photon-transfer CSV and report capacity with intervals",
                       description="Fit the Eq. 1 noise model to a photon-transfer CSV by MCMC and "
                                   "report every parameter, the derived figures and the information "
                                   "capacity with 68 %% and 95 %% credible intervals.")
    p.add_argument("csv", help="photon-transfer CSV (format: README, 'Photon-transfer CSV')")
    p.add_argument("--json", action="store_true", help="print the result as JSON (the contract's fit JSON)")
    p.add_argument("--seed", type=int, default=None, help="random seed: the same seed gives the same numbers")
    p.add_argument("--out", metavar="DIR", help="also write result.json, report.txt, posterior.nc "
                                               "(ArviZ InferenceData), ptc.png and corner.png into DIR")
    p.add_argument("--quality", choices=("fast", "standard", "accurate"), default="standard",
                   help="speed/accuracy preset (README, 'Quality presets'); default standard")
    p.add_argument("--scene-exposure-s", type=float, default=None,
                   help="exposure time (s) at which TR and capacity are evaluated "
                        "(default: median exposure time of the unclipped rows)")
    p.add_argument("--progress", dest="progress", action="store_true", default=None,
                   help="show a progress bar (default: when stderr is a terminal)")
    p.add_argument("--no-progress", dest="progress", action="store_false")
    _add_metadata_overrides(p)
    p.set_defaults(func=_cmd_fit)

    from .raw import add_ingest_arguments, run_ingest

    p = sub.add_parser("ingest", help="frames (RAW/DNG/TIFF/PNG/npy) -> photon-transfer CSV",
                       description="Compute a photon-transfer CSV from flat-field and dark frames "
                                   "described by a manifest CSV or an EMVA 1288 descriptor "
                                   "(docs/ingest.md).")
    add_ingest_arguments(p)
    p.set_defaults(func=run_ingest)
    return parser


def _cmd_fit(args) -> int:
    from .api import fit, load
    from .posterior import Scene
    from .ptc import PTCInputError
    from .report import format_text, to_json, write_outputs

    overrides = {k: getattr(args, k) for k in _OVERRIDE_KEYS if getattr(args, k, None) is not None}
    try:
        data = load(args.csv, **overrides)
    except PTCInputError as e:
        raise InputError(str(e)) from None
    scene = None
    if args.scene_exposure_s is not None:
        if not args.scene_exposure_s >= 0:
            raise InputError(f"--scene-exposure-s must be >= 0, got {args.scene_exposure_s}")
        scene = Scene(exposure_time_s=args.scene_exposure_s, source="--scene-exposure-s")
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    result = fit(data, seed=args.seed, quality=args.quality, scene=scene, progress=progress)
    if args.out:
        write_outputs(result, args.out)
    sys.stdout.write(to_json(result) if args.json else format_text(result))
    return 0


def main(argv=None) -> int:
    warnings.filterwarnings("ignore", category=FutureWarning)  # ArviZ's refactor notice
    warnings.filterwarnings("ignore", module="arviz")
    from .fit import ConvergenceWarning

    warnings.filterwarnings("ignore", category=ConvergenceWarning)  # reported in the output instead
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except InputError as e:
        print(f"bayescap: error: {e}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("bayescap: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
