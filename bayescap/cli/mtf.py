"""``bayescap mtf``: slanted-edge MTF of an image with bootstrap intervals."""

from __future__ import annotations

import sys
import warnings

from bayescap.exceptions import InputError


def _cmd_mtf(args) -> int:
    import json

    from bayescap.exceptions import MTFInputError, MTFWarning
    from bayescap.io.atomic import atomic_write_text, output_problem
    from bayescap.measure import measure_sfr, read_image
    from bayescap.measure.table import mtf_table_text

    if args.out:  # before any work: never over the image, and a place that can be written
        problem = output_problem(args.out, [args.image])
        if problem:
            raise InputError(problem)
    roi = None
    if args.roi:
        try:
            roi = tuple(int(v) for v in args.roi.split(","))
            if len(roi) != 4:
                raise ValueError
        except ValueError:
            raise InputError(f"--roi must be x0,y0,x1,y1 (four integers), got '{args.roi}'") from None
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
    except MTFInputError as e:
        raise InputError(str(e)) from None
    for w in r.warnings:
        print(f"bayescap mtf: warning: {w}", file=sys.stderr)
    out_text = mtf_table_text(r) if args.out else None
    if args.json:
        sys.stdout.write(json.dumps(r.to_dict(), indent=2, allow_nan=False, default=float) + "\n")
    else:
        lo, hi = r.mtf50_ci(0.95) if r.mtf_samples.shape[0] else (float("nan"), float("nan"))
        sys.stdout.write(
            f"{args.image}: edge {r.orientation}, angle {r.edge_angle_deg:.2f} deg, channel {r.channel}\n"
            f"MTF50 = {r.mtf50_cy_per_px:.4f} cy/px, 95 % interval [{lo:.4f}, {hi:.4f}] "
            f"({r.mtf_samples.shape[0]} bootstrap draws)\n"
            f"sampling efficiency {100 * r.sampling_efficiency:.0f} %\n"
        )
    if out_text is not None:  # after the result is printed: a write error does not lose it
        sys.stdout.flush()
        try:
            atomic_write_text(args.out, out_text)
        except OSError as e:
            print(f"bayescap: error: cannot write {args.out} ({e.strerror or e}); nothing was written", file=sys.stderr)
            return 1
    return 0
