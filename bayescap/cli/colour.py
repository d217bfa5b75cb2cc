"""``bayescap colour``: colour sensitivity, colour capacity and camera scores of a Bayer sensor.

    bayescap colour MANIFEST|DESCRIPTOR|DIR [--ccm SPEC] [--wb as-shot|daylight|flat|R,G,B] [--json] [--out DIR]
        [--domain cube|reflectances --sensitivities NAME|CSV [--reflectances NAME] [--illuminant NAME]]
        [--no-clip-output]
    bayescap colour ptc_R.csv ptc_Gr.csv ptc_Gb.csv ptc_B.csv --ccm SPEC

The four CFA channels are measured from the frames in one pass (or read from four channel CSVs),
fitted as one readout chain (:mod:`bayescap.colour.cfa_fit`), and CS is computed per posterior
draw (:mod:`bayescap.colour.sensitivity`) with the colour-correction matrix of the RAW metadata or
``--ccm`` (:mod:`bayescap.colour.raw_metadata`). Bad input: one line, exit 2, nothing written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bayescap.cli.common import _OVERRIDE_KEYS, EXIT_FAILURE, EXIT_INPUT, _add_metadata_overrides, seed_arg
from bayescap.exceptions import InputError

__all__ = ["add_colour_arguments", "run_colour", "register", "colour_text"]

OUT_FILES = ("colour.json", "colour.txt")


def add_colour_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="a frame set of RAW/DNG flats and darks (manifest CSV, EMVA 1288 descriptor or a directory "
        "holding one), or the four channel CSVs of 'bayescap ingest --channel all'",
    )
    p.add_argument(
        "--ccm",
        default=None,
        metavar="SPEC",
        help="colour-correction matrix (white-balanced camera RGB -> linear sRGB): a RAW/DNG file (its "
        "metadata), a text file of 3 rows of 3 numbers, or 9 numbers inline, row by row "
        "(default: the first frame's RAW metadata)",
    )
    p.add_argument(
        "--ccm-rel-sd",
        type=float,
        default=0.02,
        metavar="FRAC",
        help="stated relative uncertainty of each CCM element, drawn into CS (default 0.02; 0: exact)",
    )
    p.add_argument(
        "--wb",
        default=None,
        metavar="as-shot|daylight|flat|R,G,B",
        help="white-balance gains: the RAW file's as-shot or daylight balance, 'flat' (the flats' own "
        "channel ratios: they become grey) or three numbers (default: as-shot, else flat)",
    )
    p.add_argument(
        "--domain",
        choices=("cube", "reflectances"),
        default="cube",
        help="colours counted: the full raw cube (default), or 'reflectances': every exposure of every mixture "
        "of a reflectance set's colours under an illuminant, through the camera's spectral sensitivities "
        "(--reflectances, --illuminant, --sensitivities; colour-science data)",
    )
    p.add_argument(
        "--reflectances",
        default="ColorChecker N Ohta",
        metavar="NAME",
        help="--domain reflectances: colour-science's reflectance set (SDS_COLOURCHECKERS; default "
        "'ColorChecker N Ohta')",
    )
    p.add_argument(
        "--illuminant",
        default="D65",
        metavar="NAME",
        help="--domain reflectances: colour-science's illuminant (SDS_ILLUMINANTS; default D65)",
    )
    p.add_argument(
        "--sensitivities",
        default=None,
        metavar="NAME|CSV",
        help="--domain reflectances (required there): the camera's spectral sensitivities, a colour-science "
        "name ('Nikon 5100 (NPL)', 'Sigma SDMerill (NPL)') or a CSV of wavelength_nm,R,G,B rows; their "
        "channel balance is set by the white balance (a perfect white gives raw 1/wb)",
    )
    p.add_argument(
        "--no-clip-output",
        dest="clip_output",
        action="store_false",
        help="count every colour of the domain, also those beyond the output's [0, white] after the CCM "
        "(default: clipped, as in an output image; docs/colour.md)",
    )
    p.add_argument("--no-floor", action="store_true", help="CS without Eq. 7's max(σ, 1) floor")
    p.add_argument(
        "--out-bits", type=int, default=8, help="bits of the output grid the floor is counted on (default 8)"
    )
    p.add_argument(
        "--roi", default=None, help="frames: region of interest x0,y0,x1,y1 or a centred fraction (default 0.5)"
    )
    p.add_argument("--format", dest="format", choices=("auto", "manifest", "emva"), default="auto")
    p.add_argument(
        "--quality",
        choices=("fast", "standard", "accurate"),
        default="fast",
        help="each channel's fit preset (default fast: the checked Laplace-IS path, MCMC where its check fails)",
    )
    p.add_argument("--seed", type=seed_arg, default=0, help="random seed (default 0)")
    p.add_argument(
        "--exposure-s", type=float, default=None, help="exposure time of the scene (default: the median unclipped one)"
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON (a 'colour' block)")
    p.add_argument("--out", metavar="DIR", default=None, help="also write colour.json and colour.txt into DIR")
    _add_metadata_overrides(p)  # the sensor's size and optics: the capacities and the print normalisation


def _wb_from_flats(tables) -> np.ndarray:
    """Gains that make the flats grey: G's signal over each channel's, on rows no channel clips
    (G the mean of Gr and Gb)."""
    sig = {c: np.asarray(t.signal_dn, float) for c, t in tables.items()}
    ok = np.ones(sig["R"].size, bool)
    for t in tables.values():
        if t.frac_saturated is not None:
            ok &= np.asarray(t.frac_saturated) < 1e-3
        ok &= np.asarray(t.mean_dn) < 0.7 * (t.adc_max_dn or np.inf)
    if not np.any(ok):
        raise InputError("--wb flat: every row has a clipped channel; give --wb R,G,B")
    s = {c: float(np.sum(v[ok])) for c, v in sig.items()}
    g = 0.5 * (s["Gr"] + s["Gb"])
    if min(s["R"], s["B"], g) <= 0:
        raise InputError("--wb flat: a channel has no signal above dark in the flats; give --wb R,G,B")
    return np.array([g / s["R"], 1.0, g / s["B"]])


def _white_balance(spec, raw_colour, tables):
    if spec is None:
        if raw_colour is not None and raw_colour.wb_gains is not None:
            return raw_colour.wb_gains, raw_colour.wb_source
        return _wb_from_flats(tables), "the flats (their channel ratios made grey)"
    key = spec.strip().lower()
    if key in ("as-shot", "daylight"):
        if raw_colour is None:
            raise InputError(f"--wb {spec}: needs RAW frames (or --ccm RAWFILE) to read the camera's white balance")
        gains = raw_colour.wb_gains if key == "as-shot" else raw_colour.daylight_wb_gains
        if gains is None or (key == "as-shot" and "as shot" not in raw_colour.wb_source):
            raise InputError(
                f"{raw_colour.path}: the RAW metadata hold no {key} white balance; give --wb R,G,B or flat"
            )
        return gains, f"{raw_colour.path.name}: {key}"
    if key == "flat":
        return _wb_from_flats(tables), "the flats (their channel ratios made grey)"
    try:
        gains = np.array([float(v) for v in spec.split(",")])
    except ValueError:
        gains = np.array([])
    if gains.size != 3 or not np.all(np.isfinite(gains)) or np.any(gains <= 0):
        raise InputError(f"--wb {spec!r}: expected as-shot, daylight, flat or three positive numbers R,G,B")
    return gains, "user (--wb)"


def _colour_inputs(args):
    """The tables, the CCM (bayescap.colour.ccm.CCM) and the white balance; InputError on bad input."""
    from bayescap.colour.ccm import ccm_from_matrix
    from bayescap.colour.raw_metadata import parse_ccm, read_raw_colour
    from bayescap.io.cfa import load_cfa

    if not 1 <= args.out_bits <= 16:
        raise InputError(f"--out-bits must be a whole number of bits from 1 to 16, got {args.out_bits}")
    if not (0.0 <= args.ccm_rel_sd < 1.0):
        raise InputError(f"--ccm-rel-sd must be in [0, 1), got {args.ccm_rel_sd:g}")
    given = parse_ccm(args.ccm) if args.ccm is not None else None  # before the frames are read
    cfa = load_cfa(args.inputs, roi=args.roi, fmt=args.format)
    raw_colour = None
    if cfa.first_frame is not None and cfa.first_frame.suffix.lower() not in (".png", ".tif", ".tiff", ".npy"):
        raw_colour = read_raw_colour(cfa.first_frame)
    if given is not None:
        matrix, source, rc = given
        raw_colour = rc or raw_colour
    elif raw_colour is not None and raw_colour.ccm is not None:
        matrix, source = raw_colour.ccm, raw_colour.ccm_source
    else:
        where = raw_colour.path if raw_colour is not None else cfa.source
        raise InputError(f"{where}: no colour-correction matrix in the metadata; give --ccm FILE or 9 numbers")
    try:
        ccm = ccm_from_matrix(
            matrix, source=source, rel_sd=args.ccm_rel_sd, n_draws=4000 if args.ccm_rel_sd else None, seed=args.seed
        )
    except ValueError as e:
        raise InputError(str(e)) from None
    wb, wb_source = _white_balance(args.wb, raw_colour, cfa.tables)
    return cfa, ccm, wb, wb_source


def _domain(args, wb):
    """(domain, its name) of ``--domain``; InputError on a bad reflectance set, illuminant or
    sensitivities."""
    if args.domain == "cube":
        return "cube", None
    from bayescap.colour.spectral import load_sensitivities, reflectance_domain

    if args.sensitivities is None:
        raise InputError(
            "--domain reflectances needs --sensitivities NAME|CSV (the camera's spectral sensitivities: "
            "'Nikon 5100 (NPL)', 'Sigma SDMerill (NPL)' or a CSV of wavelength_nm,R,G,B)"
        )
    try:
        sens = load_sensitivities(args.sensitivities)
        resp = reflectance_domain(sens, args.reflectances, args.illuminant, wb_gains=wb)
    except ValueError as e:
        raise InputError(str(e)) from None
    name = (
        f"{resp.shape[0]} patches of {args.reflectances} under {args.illuminant} through the sensitivities "
        f"{sens.name} (channels balanced so that a perfect white gives raw 1/wb)"
    )
    return resp, name


def colour_text(doc: dict) -> str:
    """The human-readable result (what ``bayescap colour`` prints)."""
    from bayescap.report.colour_section import limit_text

    def iv(s, fmt="{:.4g}"):
        if not isinstance(s, dict) or s.get("median") is None or None in (s.get("ci95") or [None]):
            return limit_text(s, fmt)
        lo, hi = s["ci95"]
        return f"{fmt.format(s['median'])} [{fmt.format(lo)}, {fmt.format(hi)}] {s.get('unit', '')}".rstrip()

    c = doc["colour"]
    f = c["cfa_fit"]
    lines = [f"bayescap colour: {doc['input']}  (medians, 95 % credible intervals)", ""]
    lines.append(f"Colour sensitivity CS      {iv(c['cs_bits'])}")
    lines.append(f"  no floor, raw cube       {iv(c['cs_no_floor_bits'])}")
    per_channel: dict = {}
    for k, v in c["scores"].items():
        base, _, ch = k.rpartition("_")
        if ch in ("R", "Gr", "Gb", "B"):
            per_channel.setdefault(base, []).append(f"{ch} {iv(v)}")
        elif k != "colour_depth_bits":
            lines.append(f"  {k:<24} {iv(v)}")
    for base, items in per_channel.items():
        lines.append(f"  {base:<24} " + ";  ".join(items))
    for k, v in c["capacity"].items():
        lines.append(f"  capacity {k:<15} {iv(v, '{:.5g}')}")
    ccm = c["ccm"]
    lines += ["", f"CCM ({ccm['source']}; uncertainty {ccm['uncertainty']})"]
    for row, gain in zip(ccm["matrix"], ccm["noise_gain"]):
        lines.append("  " + "  ".join(f"{v:8.4f}" for v in row) + f"   noise gain {gain:.3f}")
    lines.append(f"  condition number {ccm['condition_number']:.3g}")
    wb = c["white_balance"]
    lines.append(f"White balance R, G, B      {', '.join(f'{v:.4f}' for v in wb['gains'])}  ({wb['source']})")
    lines += ["", f"CFA fit: {f['fit']}; {'converged' if f['converged'] else 'NOT CONVERGED'}"]
    for k, v in f["shared"].items():
        lines.append(f"  shared {k:<26} {iv(v)}")
    kc = f["k_check"]
    verdict = "agree" if kc["passed"] else "DISAGREE"
    lines.append(
        f"  K check: the channels' K {verdict} (chi2 {kc['chi2']:.2f}, {kc['dof']} dof, p = {kc['p_value']:.3g}; max ratio {kc['max_ratio']:.4f})"
    )
    lines.append("  per channel (separate fit | joint):")
    for ch in f["channels"]:
        sep, joi = f["separate"][ch], f["joint"][ch]
        lines.append(
            f"    {ch:<3} K {iv(sep['conversion_gain_e_per_dn'])} | {iv(joi['conversion_gain_e_per_dn'])}"
            + (f";  PRNU {iv(joi['prnu_percent'])}" if "prnu_percent" in joi else "")
        )
    for n in f["notes"] + c.get("notes", []):
        lines.append(f"  note: {n}")
    said = set(f["notes"] + c.get("notes", []))
    for n, chs in _by_note(f.get("separate_notes", {})).items():
        if n not in said:
            lines.append(f"  note ({'all channels' if len(chs) == len(f['channels']) else ', '.join(chs)}): {n}")
    lines += ["", "Definitions:"]
    lines.append(f"  CS: {c['choices']['definition']}")
    lines.append(f"  domain: {c['choices']['domain']}; floor: {c['choices']['floor']}")
    if "clipping" in c["choices"]:
        lines.append(f"  clipping: {c['choices']['clipping']}")
    if "evaluation" in c["choices"]:
        mc = c["choices"].get("cs_interval_end_mc_error_frac_of_width")
        lines.append(
            f"  CS evaluated: {c['choices']['evaluation']}"
            + (f"; its 95 % interval's ends to a Monte Carlo error of {mc:.2g} of the width" if mc is not None else "")
        )
    for k, v in c["definitions"].items():
        lines.append(f"  {k}: {v}")
    return "\n".join(lines) + "\n"


def _by_note(notes: dict) -> dict:
    """{note: [channels]} from {channel: [notes]}: a caveat the channels share is printed once."""
    out: dict = {}
    for ch, ns in notes.items():
        for n in ns:
            out.setdefault(n, []).append(ch)
    return out


def run_colour(args) -> int:
    """``bayescap colour``: 0 done, 2 bad input (one line, nothing written), 1 an output not written."""
    from bayescap import __version__
    from bayescap.api import default_scene
    from bayescap.colour.cfa_fit import colour_summary, fit_cfa
    from bayescap.io.atomic import output_problem, write_files_atomically

    def refuse(msg) -> int:
        print(f"bayescap colour: error: {msg}", file=sys.stderr)
        return EXIT_INPUT

    if args.out is not None:
        problem = output_problem(args.out, args.inputs, directory=True, option="--out", names=OUT_FILES)
        if problem:
            return refuse(problem)
    if args.domain == "cube" and args.sensitivities is not None:
        return refuse("--sensitivities is for --domain reflectances")
    try:
        cfa, ccm, wb, wb_source = _colour_inputs(args)
        domain, domain_name = _domain(args, wb)
    except InputError as e:
        return refuse(e)
    for kind, text in cfa.notices:  # what the ingest assumed, and what looks implausible in the tables
        print(f"bayescap colour: {kind}: {text}", file=sys.stderr)
    fit = fit_cfa(cfa.tables, seed=args.seed, quality=args.quality)
    md = dict(cfa.tables["Gr"].metadata)
    md.update({k: getattr(args, k) for k in _OVERRIDE_KEYS if getattr(args, k, None) is not None})
    width, height = md.get("width_px"), md.get("height_px")
    n_sensor = float(width) * float(height) if width and height else None
    t = args.exposure_s if args.exposure_s is not None else default_scene(cfa.tables["Gr"]).exposure_time_s
    summary = colour_summary(
        fit,
        ccm,
        wb,
        exposure_time_s=t,
        n_pixels_sensor=n_sensor,
        metadata=md,
        domain=domain,
        domain_name=domain_name,
        floor=not args.no_floor,
        out_bits=args.out_bits,
        clip_output=args.clip_output,
    )
    summary["ccm"] = ccm.to_dict()
    summary["white_balance"] = {"gains": np.asarray(wb, float).tolist(), "source": wb_source}
    summary["cfa_fit"] = fit.to_dict()
    doc = {
        "bayescap_version": __version__,
        "input": " ".join(str(p) for p in args.inputs),
        "sensor": {k: v for k, v in md.items() if k != "channel"},
        "colour": summary,
    }
    text = colour_text(doc)
    body = json.dumps(doc, indent=2, default=float) + "\n"
    sys.stdout.write(body if args.json else text)
    if args.out is not None:
        out = Path(args.out)
        try:
            out.mkdir(parents=True, exist_ok=True)
            write_files_atomically({out / "colour.json": body, out / "colour.txt": text})
        except OSError as e:
            print(f"bayescap colour: error: cannot write {args.out} ({e.strerror or e})", file=sys.stderr)
            return EXIT_FAILURE
    return 0


def register(sub, epilog=None) -> None:
    """Add ``bayescap colour`` to the sub-command parsers ``sub``."""
    p = sub.add_parser(
        "colour",
        help="colour sensitivity (CS), colour capacity and scores of a Bayer sensor, with intervals",
        description="Fit the four CFA channels of RAW/DNG flats as one readout chain and report colour "
        "sensitivity (DxOMark's colour depth), colour capacity and camera scores with 95 % credible "
        "intervals (docs/colour_cli.md).",
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_colour_arguments(p)
    p.set_defaults(func=run_colour)


def add_colour_result_argument(p: argparse.ArgumentParser) -> None:
    """``--colour FILE`` (``report``, ``datasheet``): add the colour section of a ``bayescap colour`` result."""
    p.add_argument(
        "--colour",
        metavar="FILE",
        default=None,
        help="add a colour section: the colour.json of 'bayescap colour --out DIR' (or its --json output)",
    )


def colour_result_from_args(args) -> dict | None:
    """The ``--colour`` JSON (None without it); :class:`InputError` naming the file when it is not one."""
    if getattr(args, "colour", None) is None:
        return None
    from bayescap.report.colour_section import load_colour_result

    return load_colour_result(args.colour)
