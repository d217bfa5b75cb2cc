"""``bayescap mtf``: slanted-edge MTF of an image with bootstrap intervals."""

from __future__ import annotations

import sys
import warnings

from bayescap.exceptions import InputError


def _cmd_mtf(args) -> int:
    import json

    from bayescap.exceptions import MTFInputError, MTFWarning
    from bayescap.measure import measure_sfr, read_image, write_mtf_table

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
    if args.out:
        write_mtf_table(r, args.out)
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
    return 0
