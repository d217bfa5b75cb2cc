"""``bayescap sweep``: the paper's what-if studies (capacity vs pixel size, Fig. 4)."""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from bayescap.studies.sweep import (
    FORMATS_MM,
    PAPER_TR_TREND_BITS_PER_UM,
    _format_table,
    pixel_size_sweep,
)


def add_sweep_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Arguments of ``bayescap sweep``: ``pixel-size --format 1/4in --f-number 2.8 ...``."""
    from bayescap.cli.common import seed_arg

    parser.add_argument(
        "study", choices=["pixel-size"], help="pixel-size: image information capacity vs pixel pitch (paper Fig. 4)"
    )
    parser.add_argument(
        "--format",
        dest="optical_format",
        default="1/4in",
        choices=sorted(FORMATS_MM),
        help="optical format (fixed imaging area); 1/4in = 3.6 x 2.7 mm (default)",
    )
    parser.add_argument("--f-number", type=float, default=2.8, help="ideal lens f-number (default 2.8)")
    parser.add_argument("--wavelength-nm", type=float, default=555.0, help="wavelength (default 555 nm)")
    parser.add_argument(
        "--method",
        choices=["eq9", "eq8"],
        default="eq9",
        help="MTF loss: eq9 (radial, the paper's Fig. 4; default) or eq8 (2-D square)",
    )
    parser.add_argument(
        "--tr-trend",
        type=float,
        default=PAPER_TR_TREND_BITS_PER_UM,
        help="TR slope below 1.45 um in bit/um (default 0.35, the paper's); a negative value fits it per draw",
    )
    parser.add_argument(
        "--exposure-lux-s",
        type=float,
        default=None,
        help="evaluate TR at this exposure instead of over the dynamic range",
    )
    parser.add_argument(
        "--bands",
        default=None,
        metavar="SOURCES",
        help="also draw these inputs for the optimal pitch, comma-separated: table1,tr_slope,wavelength "
        "(docs/physics.md, 'Bands with every uncertain input')",
    )
    parser.add_argument(
        "--wavelength-range-nm",
        default="500,600",
        metavar="LO,HI",
        help="wavelength range drawn by --bands wavelength (default 500,600)",
    )
    parser.add_argument("--draws", type=int, default=2000, help="Table 1 draws (default 2000)")
    parser.add_argument("--seed", type=seed_arg, default=0, help="random seed (default 0)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return parser


def run_sweep(args: argparse.Namespace) -> int:
    """Run ``bayescap sweep`` from parsed arguments; prints a table or JSON; returns 0."""
    if args.study != "pixel-size":  # pragma: no cover - argparse restricts the choices
        raise ValueError(f"unknown study {args.study!r}")

    def refuse(msg):
        print(f"bayescap: error: {msg}", file=sys.stderr)
        return 2

    if args.draws < 1:
        return refuse(f"--draws must be at least 1, got {args.draws}")
    if not (0.5 <= args.f_number < math.inf):
        return refuse(f"--f-number must be a finite number >= 0.5 (the limit of a lens in air), got {args.f_number}")
    if not (0.0 < args.wavelength_nm < math.inf):
        return refuse(f"--wavelength-nm must be a finite number > 0, got {args.wavelength_nm}")
    if not math.isfinite(args.tr_trend):
        return refuse(f"--tr-trend must be a finite number (negative: no trend), got {args.tr_trend}")
    if args.exposure_lux_s is not None and not (0.0 < args.exposure_lux_s < math.inf):
        return refuse(f"--exposure-lux-s must be a finite number > 0, got {args.exposure_lux_s}")
    sources = None
    if args.bands:
        from bayescap.studies.fig4_bands import SOURCES

        sources = tuple(x.strip() for x in args.bands.split(",") if x.strip())
        bad = [x for x in sources if x not in SOURCES]
        if bad or not sources:
            return refuse(f"--bands takes a comma-separated list of {', '.join(SOURCES)}, got '{args.bands}'")
        try:
            lam = tuple(float(x) for x in args.wavelength_range_nm.split(","))
            if len(lam) != 2 or not (0 < lam[0] <= lam[1] < math.inf):
                raise ValueError
        except ValueError:
            return refuse(
                f"--wavelength-range-nm must be LO,HI in nm with 0 < LO <= HI, got '{args.wavelength_range_nm}'"
            )
    res = pixel_size_sweep(
        optical_format=args.optical_format,
        f_number=args.f_number,
        wavelength_nm=args.wavelength_nm,
        n_draws=args.draws,
        seed=args.seed,
        method=args.method,
        tr_trend_bits_per_um=None if args.tr_trend < 0 else args.tr_trend,
        exposure_lux_s=args.exposure_lux_s,
    )
    if not np.any(np.asarray(res.capacity_nominal_bits) > 0):
        # every pitch's capacity underflows (an f/1e308 lens passes no detail): no optimum to report
        return refuse(
            f"the capacity is zero at every pitch (Δs down to {float(np.min(res.delta_s_bits)):.0f} bits "
            f"at f/{args.f_number:g}, {args.wavelength_nm:g} nm): no optimal pitch exists"
        )
    bands = None
    if sources:
        from bayescap.studies.fig4_bands import capacity_bands

        bands = capacity_bands(
            np.round(np.arange(1.0, 5.2 + 1e-9, 0.005), 10),
            sources=sources,
            n_draws=args.draws,
            seed=args.seed,
            method=args.method,
            optical_format=args.optical_format,
            f_number=args.f_number,
            wavelength_range_nm=lam,
        )
    if args.json:
        d = res.to_dict()
        if bands is not None:
            d["optimal_pitch_bands"] = {**bands.optimum_summary(), "settings": bands.settings}
        print(json.dumps(d, indent=2))
    else:
        print(_format_table(res))
        if bands is not None:
            o = bands.optimum_summary()
            print(
                f"optimal pitch with {', '.join(sources)} drawn (PCHIP b', {args.draws} draws): "
                f"{o['median_um']:.3f} um, 95 % [{o['ci95_um'][0]:.3f}, {o['ci95_um'][1]:.3f}]"
                + (
                    f"; {100 * o['fraction_at_grid_edge']:.0f} % of draws at the grid edge"
                    if o["fraction_at_grid_edge"]
                    else ""
                )
            )
    return 0


def main(argv=None) -> int:
    """``bayescap sweep pixel-size ...`` with ``argv`` (default: ``sys.argv[1:]``) as its arguments."""
    parser = add_sweep_arguments(argparse.ArgumentParser(prog="bayescap sweep", description=__doc__.split("\n")[0]))
    return run_sweep(parser.parse_args(argv))


def register(sub) -> None:
    """Add ``bayescap sweep`` to the sub-command parsers ``sub``."""
    p = sub.add_parser(
        "sweep",
        help="what-if studies from the paper (capacity vs pixel size, Fig. 4)",
        description="Capacity vs pixel pitch at a fixed optical format with Table 1's "
        "parameter ranges drawn (docs/physics.md).",
    )
    add_sweep_arguments(p)
    p.set_defaults(func=run_sweep)
