"""Command line: a thin layer over the Python API.

    bayescap fit sensor.csv [--json] [--seed N] [--out DIR] [--quality fast|standard|accurate]
                            [--fast-tolerance FRAC] [--fast-confidence P|none]   (--quality fast)

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


def seed_arg(text: str) -> int:
    """argparse type of ``--seed``: a whole number >= 0 (numpy's SeedSequence refuses negative
    seeds, with a traceback: found 2026-11-25)."""
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
    p.add_argument("--fast-tolerance", type=float, default=None, metavar="FRAC",
                   help="--quality fast: the error, as a fraction of each 95 %% interval's width, every "
                        "interval end should stay within (default 0.05; the per-end Monte Carlo error "
                        "gate is 0.7 x this). Larger is faster and looser (README, Performance, 'The fast "
                        "preset's knob')")
    p.add_argument("--fast-confidence", default=None, metavar="P",
                   help="--quality fast: accept when every end is predicted within --fast-tolerance with "
                        "at least this probability (default 0.9; 'none': each end on its own gate only)")


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
    p.add_argument("csv", nargs="+", help="photon-transfer CSV (format: README, 'Photon-transfer CSV'); several "
                                         "CSVs are fitted as a batch (bayescap.batch.fit_many: the fast "
                                         "preset is vectorised across sensors)")
    p.add_argument("--json", action="store_true", help="print the result as JSON (the contract's fit JSON; "
                                                       "a JSON array of them for several CSVs)")
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="several CSVs: worker processes for the batch (default 1)")
    p.add_argument("--seed", type=seed_arg, default=None, help="random seed: the same seed gives the same numbers")
    p.add_argument("--out", metavar="DIR", help="also write result.json, report.txt, posterior.nc "
                                               "(ArviZ InferenceData), ptc.png and corner.png into DIR "
                                               "(several CSVs: into DIR/<csv name>/)")
    p.add_argument("--quality", choices=("fast", "standard", "accurate"), default="standard",
                   help="speed/accuracy preset (README, 'Performance'; docs/performance.md, 'Presets and "
                        "knobs'); default standard")
    add_fast_arguments(p)
    p.add_argument("--scene", default=None, metavar="KEY=VALUE,...",
                   help="evaluate TR and capacity for a scene: exposure_s=<s>, temperature_c=<°C> "
                        "(dark current doubles every 6 °C from the CSV's temperature_c); e.g. "
                        "--scene exposure_s=0.1,temperature_c=45")
    p.add_argument("--scene-exposure-s", type=float, default=None,
                   help="exposure time (s) at which TR and capacity are evaluated "
                        "(default: median exposure time of the unclipped rows)")
    p.add_argument("--temperature-c", type=float, default=None,
                   help="sensor temperature of the scene (°C); needs the measurement's temperature_c")
    p.add_argument("--mtf", metavar="FILE", default=None,
                   help="measured system MTF for Δs: a CSV table (freq_cy_per_px,mtf) or a slanted-edge "
                        "image (ISO 12233, with bootstrap draws so capacity carries sharpness uncertainty); "
                        "default: ideal pixel aperture x diffraction-limited lens from the metadata")
    p.add_argument("--select-model", action="store_true",
                   help="fit the nested likelihood variants (plain χ², + discrepancy, + outlier mixture) "
                        "and keep the one PSIS-LOO prefers (README, 'Model selection')")
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

    p = sub.add_parser("mtf", help="slanted-edge MTF (ISO 12233:2023) with bootstrap intervals",
                       description="Measure the MTF of a slanted edge following ISO 12233:2023 (Burns' "
                                   "sfrmat5 steps), with bootstrap draws over phase cycles of rows "
                                   "(docs/mtf.md).")
    p.add_argument("image", help="edge image: TIFF, PNG, JPEG or .npy (linear data)")
    p.add_argument("--roi", default=None, help="x0,y0,x1,y1 in pixels (end-exclusive); default whole image")
    p.add_argument("--npol", type=int, choices=range(1, 6), default=5, help="edge polynomial order (default 5)")
    p.add_argument("--channel", default=None, help="R, G, B, lum (RGB images; default lum) or mono")
    p.add_argument("--window", choices=("tukey", "hamming"), default="tukey")
    p.add_argument("--n-boot", type=int, default=200, help="bootstrap draws (default 200)")
    p.add_argument("--seed", type=seed_arg, default=0)
    p.add_argument("--correct-bin-width", action="store_true",
                   help="divide out the 1/4-pixel binning (recommended for Δs; off = ISO output)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--out", metavar="FILE.csv", help="write freq_cy_per_px,mtf,mtf_ci95_low,mtf_ci95_high")
    p.set_defaults(func=_cmd_mtf)

    from .compare import add_compare_arguments, run_compare

    p = sub.add_parser("compare", help="compare sensors: capacity at full resolution and fixed area, "
                                       "TR at H0, pairwise P(C_A > C_B)",
                       description="Fit each sensor and compare capacities with credible intervals and "
                                   "pairwise probabilities (docs/compare.md).")
    add_compare_arguments(p)
    p.set_defaults(func=run_compare)

    from .html_report import add_report_arguments, run_report

    p = sub.add_parser("report", help="self-contained HTML report of one or more sensors",
                       description="Fit the sensors and write one self-contained HTML page (docs/compare.md).")
    add_report_arguments(p)
    p.set_defaults(func=run_report)

    from .sweep import add_sweep_arguments, run_sweep

    p = sub.add_parser("sweep", help="what-if studies from the paper (capacity vs pixel size, Fig. 4)",
                       description="Capacity vs pixel pitch at a fixed optical format with Table 1's "
                                   "parameter ranges drawn (docs/physics.md).")
    add_sweep_arguments(p)
    p.set_defaults(func=run_sweep)
    return parser


def _cmd_mtf(args) -> int:
    import json

    from .mtf import MTFInputError, MTFWarning, measure_sfr, read_image, write_mtf_table

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
        with warnings.catch_warnings(record=True):   # MTFWarnings come back in r.warnings
            warnings.simplefilter("always", MTFWarning)
            r = measure_sfr(img, roi=roi, npol=args.npol, channel=args.channel, window=args.window,
                            n_boot=args.n_boot, seed=args.seed, correct_bin_width=args.correct_bin_width)
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
        sys.stdout.write(f"{args.image}: edge {r.orientation}, angle {r.edge_angle_deg:.2f} deg, channel {r.channel}\n"
                         f"MTF50 = {r.mtf50_cy_per_px:.4f} cy/px, 95 % interval [{lo:.4f}, {hi:.4f}] "
                         f"({r.mtf_samples.shape[0]} bootstrap draws)\n"
                         f"sampling efficiency {100 * r.sampling_efficiency:.0f} %\n")
    return 0


def fast_settings_from_args(args):
    """The :class:`~bayescap.fast.FastSettings` of ``--fast-tolerance``/``--fast-confidence`` (None
    when neither is given); :class:`InputError` (exit 2) for values out of range or without
    ``--quality fast``."""
    tol, conf = args.fast_tolerance, args.fast_confidence
    if tol is None and conf is None:
        return None
    if args.quality != "fast":
        raise InputError("--fast-tolerance and --fast-confidence apply to --quality fast only "
                         f"(got --quality {args.quality})")
    from dataclasses import replace

    from .fast import FastSettings

    fs = FastSettings()
    if tol is not None:
        if not 0.0 < tol < 1.0:
            raise InputError(f"--fast-tolerance must be a fraction of the interval width in (0, 1), got {tol:g}")
        # the per-end gate keeps its default ratio to the tolerance (0.035 for 0.05)
        fs = replace(fs, end_tolerance=float(tol),
                     end_mcse_max=float(tol) * FastSettings.end_mcse_max / FastSettings.end_tolerance)
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


def _cmd_fit(args) -> int:
    from .api import fit, load
    from .ptc import PTCInputError
    from .report import format_text, to_json, write_outputs

    overrides = {k: getattr(args, k) for k in _OVERRIDE_KEYS if getattr(args, k, None) is not None}
    fast_settings = fast_settings_from_args(args)
    if len(args.csv) > 1:
        return _cmd_fit_many(args, overrides, fast_settings)
    try:
        data = load(args.csv[0], **overrides)
    except PTCInputError as e:
        raise InputError(str(e)) from None
    scene = _scene_from_args(args, data)
    mtf = None
    if args.mtf:
        from .api import measured_mtf
        from .mtf import MTFInputError

        try:
            mtf = measured_mtf(args.mtf, seed=args.seed or 0)
        except MTFInputError as e:
            raise InputError(str(e)) from None
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    try:
        # a value the reader accepts but no parameter can explain (fit._no_finite_start) is refused
        # here, naming its row and column
        if args.select_model:
            from .selection import select_model

            result, _ = select_model(data, seed=args.seed, quality=args.quality, progress=progress, scene=scene,
                                     mtf=mtf, fast_settings=fast_settings)
        else:
            result = fit(data, seed=args.seed, quality=args.quality, scene=scene, progress=progress, mtf=mtf,
                         fast_settings=fast_settings)
    except PTCInputError as e:
        raise InputError(str(e)) from None
    if args.out:
        write_outputs(result, args.out)
    sys.stdout.write(to_json(result) if args.json else format_text(result))
    return 0


def _failure(path, err) -> str:
    """One batch sensor's error, one line: an input error as it names itself (file, row, column),
    anything else after the file with its type."""
    from .ptc import PTCInputError

    return str(err) if isinstance(err, PTCInputError) else f"{path}: {type(err).__name__}: {err}"


def _cmd_fit_many(args, overrides, fast_settings=None) -> int:
    """``bayescap fit a.csv b.csv ...``: every CSV checked first (a bad one stops the run before
    anything is fitted or written), then :func:`bayescap.batch.fit_many`."""
    from .api import load
    from .batch import fit_many
    from .ptc import PTCInputError
    from .report import format_text, write_outputs

    for opt, name in ((args.select_model, "--select-model"), (args.mtf, "--mtf"), (args.scene, "--scene"),
                      (args.scene_exposure_s is not None, "--scene-exposure-s"),
                      (args.temperature_c is not None, "--temperature-c")):
        if opt:
            raise InputError(f"{name} applies to one CSV at a time: fit the CSVs one by one to use it")
    if args.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {args.jobs}")
    datas = []
    for path in args.csv:
        try:
            datas.append(load(path, **overrides))
        except PTCInputError as e:
            raise InputError(str(e)) from None
    kw = {} if fast_settings is None else {"settings": fast_settings}
    results = fit_many(datas, quality=args.quality, seed=args.seed, n_jobs=args.jobs, **kw)
    failed = [(p, r) for p, r in zip(args.csv, results) if isinstance(r, BaseException)]
    if args.out:
        from pathlib import Path

        used = set()
        for path, r in zip(args.csv, results):
            if isinstance(r, BaseException):
                continue
            stem, k = Path(path).stem, 1
            while (stem if k == 1 else f"{stem}_{k}") in used:
                k += 1
            name = stem if k == 1 else f"{stem}_{k}"
            used.add(name)
            write_outputs(r, Path(args.out) / name)
    if args.json:
        import json

        docs = [r.to_dict() if not isinstance(r, BaseException) else {"input": p, "error": f"{type(r).__name__}: {r}"}
                for p, r in zip(args.csv, results)]
        sys.stdout.write(json.dumps(docs, indent=2, ensure_ascii=False, allow_nan=False) + "\n")
    else:
        for p, r in zip(args.csv, results):
            sys.stdout.write(f"bayescap: error: {_failure(p, r)}\n\n" if isinstance(r, BaseException)
                             else format_text(r) + "\n")
        sys.stdout.write(_batch_table(args.csv, results))
    for p, r in failed:
        print(f"bayescap: error: {_failure(p, r)}", file=sys.stderr)
    return 1 if failed else 0


def _batch_table(paths, results) -> str:
    """One line per CSV: method, convergence, K and capacity with 95 % intervals."""
    import numpy as np

    def q(x):
        lo, med, hi = np.quantile(x, [0.025, 0.5, 0.975])
        return f"{med:.4g} [{lo:.4g}, {hi:.4g}]"

    lines = [f"batch summary ({len(paths)} CSVs): median [95 % interval]",
             "csv | method | converged | conversion_gain_e_per_dn | capacity_bits"]
    for p, r in zip(paths, results):
        if isinstance(r, BaseException):
            lines.append(f"{p} | error | - | - | -")
            continue
        dg = r.diag
        cap = q(r.derived["capacity_bits"]) if "capacity_bits" in r.derived else "n/a"
        lines.append(f"{p} | {dg.get('method', 'mcmc')} | {'yes' if dg.get('converged') else 'NO'} | "
                     f"{q(r.draws['conversion_gain_e_per_dn'])} | {cap}")
    return "\n".join(lines) + "\n"


def _scene_from_args(args, data):
    """A Scene from --scene / --scene-exposure-s / --temperature-c, or None for the default."""
    from .api import default_scene
    from .posterior import Scene

    spec = {}
    if args.scene:
        for item in args.scene.split(","):
            if "=" not in item:
                raise InputError(f"--scene expects KEY=VALUE pairs separated by commas, got '{item}'")
            key, val = (x.strip() for x in item.split("=", 1))
            if key not in ("exposure_s", "temperature_c"):
                raise InputError(f"--scene: unknown key '{key}' (known: exposure_s, temperature_c)")
            try:
                spec[key] = float(val)
            except ValueError:
                raise InputError(f"--scene: {key} must be a number, got '{val}'") from None
    if args.scene_exposure_s is not None:
        spec["exposure_s"] = args.scene_exposure_s
    if args.temperature_c is not None:
        spec["temperature_c"] = args.temperature_c
    if not spec:
        return None
    base = default_scene(data)
    t = spec.get("exposure_s", base.exposure_time_s)
    temp = spec.get("temperature_c")
    ref = data.metadata.get("temperature_c")
    src = "--scene" if args.scene else ("--scene-exposure-s" if "exposure_s" in spec else base.source)
    try:        # Scene checks the exposure time and the temperature
        scene = Scene(exposure_time_s=t, source=src, temperature_c=temp,
                      reference_temperature_c=ref if temp is not None else None)
    except ValueError as e:
        raise InputError(str(e)) from None
    if temp is not None and ref is None:
        raise InputError(f"{data.source}: a scene temperature needs the measurement's temperature: add "
                         "'# temperature_c: <°C>' to the CSV")
    return scene


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
