"""``bayescap mtf``: slanted-edge MTF of an image with bootstrap intervals."""

from __future__ import annotations

import math
import sys
import warnings

from bayescap.exceptions import InputError


def add_lens_arguments(p) -> None:
    """Options of ``bayescap mtf`` for the detector MTF = system MTF / lens MTF."""
    p.add_argument(
        "--lens-mtf",
        metavar="LENS.csv",
        default=None,
        help="lens MTF table (columns frequency_lp_per_mm or frequency_cy_per_px, and mtf): report the "
        "detector MTF = system MTF / lens MTF (docs/mtf.md)",
    )
    p.add_argument("--pixel-pitch-um", type=float, default=None, help="pixel pitch (µm): lp/mm conversions")
    p.add_argument("--height-px", type=int, default=None, help="image height (pixels): cycles per image height")


def detector_summary_text(det) -> str:
    """A few lines: detector MTF at quarter Nyquist, half Nyquist and Nyquist with 95 % intervals."""
    lines = ["detector MTF = system MTF / lens MTF (lens taken as exact; 95 % bootstrap interval):"]
    for f in (0.125, 0.25, 0.5):
        i = int(abs(det.freq_cy_per_px - f).argmin())
        where = f"{det.freq_cy_per_px[i]:.3f} cy/px"
        if det.pixel_pitch_um is not None:
            where += f" = {det.freq_lp_per_mm[i]:.1f} lp/mm"
        if det.height_px is not None:
            where += f" = {det.freq_cy_per_image_height[i]:.0f} cy/image height"
        if det.valid[i]:
            lines.append(f"  {where}: {det.mtf[i]:.3f} [{det.ci95[0][i]:.3f}, {det.ci95[1][i]:.3f}]")
        else:
            lines.append(f"  {where}: not reported (lens MTF below {det.min_lens_mtf} or outside its table)")
    lines += [f"  note: {n}" for n in det.notes]
    return "\n".join(lines) + "\n"


#: bootstrap draws: at least enough for a 95 % interval's ends, at most what fits in memory beside the image
_N_BOOT_RANGE = (20, 100_000)


def _check_numbers(args) -> None:
    """The numeric options, before any work: one line each."""
    lo, hi = _N_BOOT_RANGE
    if not lo <= args.n_boot <= hi:
        raise InputError(
            f"--n-boot must be between {lo} and {hi:,} (a 95 % interval needs its draws), got {args.n_boot}"
        )
    pitch = getattr(args, "pixel_pitch_um", None)
    if pitch is not None and not (math.isfinite(pitch) and 0 < pitch <= 1000):
        raise InputError(f"--pixel-pitch-um must be a pixel pitch in (0, 1000] µm, got {pitch:g}")
    h = getattr(args, "height_px", None)
    if h is not None and not 0 < h <= 1_000_000:
        raise InputError(f"--height-px must be a positive number of pixels, got {h}")


def _cmd_mtf(args) -> int:
    import json

    from bayescap.exceptions import MTFInputError, MTFWarning
    from bayescap.io.atomic import atomic_write_text, output_problem
    from bayescap.measure import measure_sfr, read_image
    from bayescap.measure.table import mtf_table_text

    if args.out:  # before any work: never over an input (the image, the lens table), and a place that can be written
        problem = output_problem(args.out, [args.image] + ([args.lens_mtf] if getattr(args, "lens_mtf", None) else []))
        if problem:
            raise InputError(problem)
    _check_numbers(args)
    roi = None
    if args.roi:
        try:
            roi = tuple(int(v) for v in args.roi.split(","))
            if len(roi) != 4:
                raise ValueError
        except ValueError:
            raise InputError(f"--roi must be x0,y0,x1,y1 (four integers), got '{args.roi}'") from None
    lens = None
    if getattr(args, "lens_mtf", None):
        from bayescap.measure.detector import read_lens_mtf_table

        try:
            lens = read_lens_mtf_table(args.lens_mtf)
            if lens.unit == "lp/mm" and args.pixel_pitch_um is None:
                raise MTFInputError(f"{args.lens_mtf}: the lens table is in lp/mm: give --pixel-pitch-um")
        except MTFInputError as e:
            raise InputError(str(e)) from None
    try:
        img = read_image(args.image)
        with warnings.catch_warnings(record=True):  # MTFWarnings come back in r.warnings
            warnings.simplefilter("always", MTFWarning)
            r = measure_sfr(
                img,
                roi=roi,
                npol=args.npol,
                channel=args.channel,
                window=args.window,
                n_boot=args.n_boot,
                seed=args.seed,
                correct_bin_width=args.correct_bin_width,
            )
    except MTFInputError as e:  # the edge analysis' own messages do not know the file: name it
        msg = str(e)
        raise InputError(msg if msg.startswith(str(args.image)) else f"{args.image}: {msg}") from None
    for w in r.warnings:
        print(f"bayescap mtf: warning: {w}", file=sys.stderr)
    det = None
    if lens is not None:
        from bayescap.measure.detector import detector_mtf, detector_table_text

        det = detector_mtf(r, lens, pixel_pitch_um=args.pixel_pitch_um, height_px=args.height_px)
    out_text = (mtf_table_text(r) if det is None else detector_table_text(det)) if args.out else None
    if args.json:
        d = r.to_dict()
        if det is not None:
            d["detector"] = det.to_dict()
        sys.stdout.write(json.dumps(d, indent=2, allow_nan=False, default=float) + "\n")
    else:
        lo, hi = r.mtf50_ci(0.95) if r.mtf_samples.shape[0] else (float("nan"), float("nan"))
        sys.stdout.write(
            f"{args.image}: edge {r.orientation}, angle {r.edge_angle_deg:.2f} deg, channel {r.channel}\n"
            f"MTF50 = {r.mtf50_cy_per_px:.4f} cy/px, 95 % interval [{lo:.4f}, {hi:.4f}] "
            f"({r.mtf_samples.shape[0]} bootstrap draws)\n"
            f"sampling efficiency {100 * r.sampling_efficiency:.0f} %\n"
        )
        if det is not None:
            sys.stdout.write(detector_summary_text(det))
    if out_text is not None:  # after the result is printed: a write error does not lose it
        sys.stdout.flush()
        try:
            atomic_write_text(args.out, out_text)
        except OSError as e:
            print(f"bayescap: error: cannot write {args.out} ({e.strerror or e}); nothing was written", file=sys.stderr)
            return 1
    return 0
