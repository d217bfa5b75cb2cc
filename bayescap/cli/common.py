"""What the commands share: the seed and fast-path options, metadata overrides, the exit status of an input error."""

from __future__ import annotations

import argparse

from bayescap.exceptions import InputError

#: exit statuses: 0 done; 1 a failure that is not the input's (an output that could not be
#: written, a sensor of a batch that failed); 2 bad input or usage; 3 ``--strict`` and a result that
#: is not converged
EXIT_FAILURE = 1
EXIT_INPUT = 2
EXIT_NOT_CONVERGED = 3
#: standard output closed early (128 + SIGPIPE, as a shell reports it)
EXIT_BROKEN_PIPE = 141


STRICT_HELP = (
    "exit with status 3 when a result is not converged (or a fast path was rejected without a "
    "fallback), after writing the outputs: scripts can tell without reading the JSON"
)


def add_strict_argument(p) -> None:
    """``--strict`` (``fit``, ``report``, ``datasheet``), read back by :func:`strict_status`."""
    p.add_argument("--strict", action="store_true", help=STRICT_HELP)


def strict_status(args, results) -> int:
    """0, or with ``--strict`` :data:`EXIT_NOT_CONVERGED` (one line on standard error) when a
    result of ``results`` (FitResults; exceptions of a batch are skipped) is not converged (a
    rejected fast path without a fallback is flagged not converged too)."""
    import sys

    bad = [r for r in results if not isinstance(r, BaseException) and not r.diag.get("converged")]
    if getattr(args, "strict", False) and bad:
        print(f"bayescap: {len(bad)} of {len(results)} result(s) NOT CONVERGED (--strict)", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def add_progress_arguments(p) -> None:
    """``--progress``/``--no-progress`` and ``-q``/``--quiet`` (every command that fits), read back by
    :func:`progress_enabled` and :func:`quiet`."""
    p.add_argument(
        "--progress",
        dest="progress",
        action="store_true",
        default=None,
        help="show progress bars on standard error (default: when standard error is a terminal)",
    )
    p.add_argument(
        "--no-progress",
        dest="progress",
        action="store_false",
        help="no progress bars, even on a terminal (logs, CI)",
    )
    p.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="print only errors and what was asked for: no progress bars, no 'wrote ...' lines; with "
        "--out, fit prints no report (it is in DIR/report.txt) unless --json",
    )


def progress_enabled(args) -> bool:
    """Progress bars for ``args``: never with ``--quiet``; else ``--progress``/``--no-progress``, or
    whether standard error is a terminal."""
    import sys

    if getattr(args, "quiet", False):
        return False
    chosen = getattr(args, "progress", None)
    return sys.stderr.isatty() if chosen is None else bool(chosen)


def quiet(args) -> bool:
    """``--quiet`` was given."""
    return bool(getattr(args, "quiet", False))


def say(args, text: str) -> None:
    """A status line (``wrote ...``) on standard output, unless ``--quiet``."""
    if not quiet(args):
        print(text)


def seed_arg(text: str) -> int:
    """argparse type of ``--seed``: a whole number >= 0 (numpy's SeedSequence refuses negative
    seeds, with a traceback)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {v}")
    return v


def add_fast_arguments(p):
    """``--fast-tolerance``, ``--fast-confidence`` (``fit``, ``compare``, ``report``): the fast preset's
    check, read back by :func:`fast_settings_from_args`."""
    p.add_argument(
        "--fast-tolerance",
        type=float,
        default=None,
        metavar="FRAC",
        help="--quality fast: the error, as a fraction of each 95 %% interval's width, every "
        "interval end should stay within (default 0.05; the per-end Monte Carlo error "
        "gate is 0.7 x this). Larger is faster and looser (docs/performance.md, "
        "'The fast preset')",
    )
    p.add_argument(
        "--fast-confidence",
        default=None,
        metavar="P",
        help="--quality fast: accept when every end is predicted within --fast-tolerance with "
        "at least this probability (default 0.9; 'none': each end on its own gate only)",
    )


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


_OVERRIDE_KEYS = (
    "pixel_pitch_um",
    "width_px",
    "height_px",
    "adc_bits",
    "f_number",
    "wavelength_nm",
    "fill_factor",
    "sensor",
)


def fast_settings_from_args(args):
    """The :class:`~bayescap.inference.FastSettings` of ``--fast-tolerance``/``--fast-confidence`` (None
    when neither is given); :class:`InputError` (exit 2) for values out of range or without
    ``--quality fast``."""
    tol, conf = args.fast_tolerance, args.fast_confidence
    if tol is None and conf is None:
        return None
    if args.quality != "fast":
        raise InputError(
            f"--fast-tolerance and --fast-confidence apply to --quality fast only (got --quality {args.quality})"
        )
    from dataclasses import replace

    from bayescap.inference import FastSettings

    fs = FastSettings()
    if tol is not None:
        if not 0.0 < tol < 1.0:
            raise InputError(f"--fast-tolerance must be a fraction of the interval width in (0, 1), got {tol:g}")
        # the per-end gate keeps its default ratio to the tolerance (0.035 for 0.05)
        fs = replace(
            fs,
            end_tolerance=float(tol),
            end_mcse_max=float(tol) * FastSettings.end_mcse_max / FastSettings.end_tolerance,
        )
    if conf is not None:
        if str(conf).strip().lower() == "none":
            fs = replace(fs, end_confidence=None)
        else:
            try:
                c = float(conf)
            except ValueError:
                c = float("nan")
            if not 0.0 < c < 1.0:
                raise InputError(f"--fast-confidence must be a probability in (0, 1) or 'none', got {conf!r}")
            fs = replace(fs, end_confidence=c)
    return fs


def add_comparison_arguments(p: argparse.ArgumentParser) -> None:
    """The options ``compare`` and ``report`` share: the imaging area, H0, mid-grey, seed, preset."""
    from bayescap.studies.compare_defaults import (
        DEFAULT_AREA,
        DEFAULT_H0_LUX_S,
        DEFAULT_MID_GREY,
        DEFAULT_PRACTICAL_DIFFERENCE,
        DEFAULT_QUALITY,
    )

    p.add_argument(
        "--area",
        default=DEFAULT_AREA,
        help="fixed imaging area: an optical format (1/4in, 1/3.2in, 1/3in, 2/3in, ...), WxHmm, "
        "or none (default 1/4in)",
    )
    p.add_argument(
        "--h0",
        type=float,
        default=DEFAULT_H0_LUX_S,
        metavar="LUX_S",
        help="average photometric exposure H0 (lux·s) for TR and capacity, as Fig. 8(a) (default 0.4)",
    )
    p.add_argument(
        "--mid-grey",
        type=float,
        default=DEFAULT_MID_GREY,
        dest="mid_grey",
        help="fraction of the top of the signal range where the scene's mean is placed (default 0.18)",
    )
    p.add_argument(
        "--seed", type=seed_arg, default=0, help="random seed of the run (each sensor's seed derives from it)"
    )
    p.add_argument(
        "--quality",
        choices=("fast", "standard", "accurate"),
        default=DEFAULT_QUALITY,
        help="sampler preset for every fit (default fast: several sensors are fitted; "
        "use standard or accurate for final numbers)",
    )
    p.add_argument(
        "--practical-difference",
        "--rope",
        dest="practical_difference",
        type=float,
        default=DEFAULT_PRACTICAL_DIFFERENCE,
        metavar="FRAC",
        help="the capacity difference that matters, as a fraction: P(C_A > (1+FRAC)·C_B) is printed "
        "beside P(C_A > C_B), and the ratio inside [1/(1+FRAC), 1+FRAC] counts as practically "
        "equivalent (the region of practical equivalence; default 0.01 = 1 %%)",
    )
    add_fast_arguments(p)
    add_progress_arguments(p)
