"""``bayescap fit``: one CSV, or several as a batch."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from bayescap.cli.common import (
    _OVERRIDE_KEYS,
    EXIT_FAILURE,
    EXIT_NOT_CONVERGED,
    fast_settings_from_args,
    progress_enabled,
    quiet,
    strict_status,
)
from bayescap.exceptions import InputError

#: a scene temperature above it (°C) is refused before fitting: no sensor works there, and the dark
#: current's 2^(ΔT/6 °C) of a much larger ΔT overflows
_MAX_SCENE_TEMPERATURE_C = 200.0


#: the CSV argument that reads the photon-transfer table from standard input
STDIN = "-"


def load_input(path, overrides):
    """:func:`bayescap.api.load` of ``path``, or of standard input for ``-`` (named ``<stdin>``)."""
    from bayescap.api import load

    if path != STDIN:
        return load(path, **overrides)
    from bayescap.io.ptc_csv import read_ptc_csv

    return read_ptc_csv("<stdin>", overrides=overrides or None, content=sys.stdin.buffer.read())


def _cmd_fit(args) -> int:
    from bayescap.api import fit
    from bayescap.exceptions import PTCInputError
    from bayescap.report.text import format_text, to_json, write_outputs

    overrides = {k: getattr(args, k) for k in _OVERRIDE_KEYS if getattr(args, k, None) is not None}
    fast_settings = fast_settings_from_args(args)
    args.csv = _expand_folders(args.csv)
    if args.out:  # before any fitting: an output over an input, or one that cannot be written
        from bayescap.io.atomic import output_problem
        from bayescap.report.text import OUTPUT_NAMES

        inputs = [p for p in args.csv if p != STDIN] + ([args.mtf] if args.mtf else [])
        problem = output_problem(args.out, inputs, directory=True, names=OUTPUT_NAMES if len(args.csv) == 1 else None)
        if problem:
            raise InputError(problem)
    seed_drawn = args.seed is None
    if seed_drawn:  # a run without --seed can still be repeated: the seed is drawn and recorded
        from bayescap.api import draw_seed

        args.seed = draw_seed()
    args.seed_drawn = seed_drawn
    if args.csv.count(STDIN) > 1:
        raise InputError("standard input ('-') can be read once: give it at most once")
    if len(args.csv) > 1:
        return _cmd_fit_many(args, overrides, fast_settings)
    try:
        data = load_input(args.csv[0], overrides)
    except PTCInputError as e:
        raise InputError(str(e)) from None
    scene = _scene_from_args(args, data)
    mtf = None
    if args.mtf:
        from bayescap.api import measured_mtf
        from bayescap.exceptions import MTFInputError

        try:
            mtf = measured_mtf(args.mtf, seed=args.seed or 0)
        except MTFInputError as e:
            raise InputError(str(e)) from None
    progress = progress_enabled(args)
    try:
        # a value the reader accepts but no parameter can explain
        # (bayescap.inference.starts._no_finite_start) is refused
        # here, naming its row and column
        if args.select_model:
            from bayescap.studies.selection import select_model

            result, _ = select_model(
                data,
                seed=args.seed,
                quality=args.quality,
                progress=progress,
                scene=scene,
                mtf=mtf,
                fast_settings=fast_settings,
            )
        else:
            result = fit(
                data,
                seed=args.seed,
                quality=args.quality,
                scene=scene,
                progress=progress,
                mtf=mtf,
                fast_settings=fast_settings,
            )
    except PTCInputError as e:
        raise InputError(str(e)) from None
    if seed_drawn:
        result.diag["seed_drawn"] = True
    # the result first: a write error below does not lose it
    if args.json:
        sys.stdout.write(to_json(result))
    elif not (quiet(args) and args.out):
        sys.stdout.write(format_text(result))
    sys.stdout.flush()
    if args.out:
        try:
            write_outputs(result, args.out)
        except OSError as e:
            print(f"bayescap: error: {write_error(args.out, e)}", file=sys.stderr)
            return EXIT_FAILURE
    return _strict_status(args, [result])


def _expand_folders(paths) -> list:
    """The inputs with each folder replaced by its ``*.csv`` files in name order (a focal plane's
    amplifier tables as one batch); a folder without one is refused."""
    from pathlib import Path

    out = []
    for p in paths:
        if Path(p).is_dir():
            found = sorted(str(f) for f in Path(p).glob("*.csv") if f.is_file())
            if not found:
                raise InputError(f"{p}: a folder without any *.csv file (give photon-transfer CSVs or their folder)")
            out += found
        else:
            out.append(p)
    return out


def _strict_status(args, results) -> int:
    """:func:`bayescap.cli.common.strict_status` (the exit status of ``--strict``)."""
    return strict_status(args, results)


def write_error(out, err: OSError) -> str:
    """A write error in one line: the output, what failed; nothing was left behind."""
    what = err.strerror or str(err)
    return f"cannot write {out} ({what}); nothing was written there"


def _failure(path, err) -> str:
    """One batch sensor's error, one line: an input error as it names itself (file, row, column),
    anything else after the file with its type."""
    from bayescap.exceptions import PTCInputError

    return str(err) if isinstance(err, PTCInputError) else f"{path}: {type(err).__name__}: {err}"


def _cmd_fit_many(args, overrides, fast_settings=None) -> int:
    """``bayescap fit a.csv b.csv ...``: every CSV checked first (a bad one stops the run before
    anything is fitted or written), then :func:`bayescap.batch.fit_many`."""
    from bayescap.batch import fit_many
    from bayescap.exceptions import PTCInputError
    from bayescap.report.text import format_text

    for opt, name in (
        (args.select_model, "--select-model"),
        (args.mtf, "--mtf"),
        (args.scene, "--scene"),
        (args.scene_exposure_s is not None, "--scene-exposure-s"),
        (args.temperature_c is not None, "--temperature-c"),
    ):
        if opt:
            raise InputError(f"{name} applies to one CSV at a time: fit the CSVs one by one to use it")
    if args.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {args.jobs}")
    scheduler, n_dask = getattr(args, "scheduler", None), getattr(args, "dask", None)
    if scheduler is not None and n_dask is not None:
        raise InputError("--scheduler and --dask: give one (an existing cluster, or a new local one)")
    if n_dask is not None and n_dask < 1:
        raise InputError(f"--dask must be at least 1 worker, got {n_dask}")
    cluster_asked = scheduler is not None or n_dask is not None
    if cluster_asked and args.jobs != 1:
        raise InputError(
            "--jobs is for the local process pool: with --scheduler or --dask the cluster's workers run the batch"
        )
    if cluster_asked and not args.out:
        raise InputError("--scheduler and --dask write every result as it finishes: give --out DIR")
    datas = []
    for path in args.csv:
        try:
            datas.append(load_input(path, overrides))
        except PTCInputError as e:
            raise InputError(str(e)) from None
    kw = {} if fast_settings is None else {"settings": fast_settings}
    if args.out:
        return _fit_many_to_folder(args, datas, kw, scheduler, n_dask)
    results = fit_many(datas, quality=args.quality, seed=args.seed, n_jobs=args.jobs, **kw)
    failed = [(p, r) for p, r in zip(args.csv, results) if isinstance(r, BaseException)]
    for r in results:
        if not isinstance(r, BaseException) and getattr(args, "seed_drawn", False):
            r.diag["seed_drawn"] = True
    if args.json:
        import json

        docs = [
            r.to_dict() if not isinstance(r, BaseException) else {"input": p, "error": f"{type(r).__name__}: {r}"}
            for p, r in zip(args.csv, results)
        ]
        sys.stdout.write(json.dumps(docs, indent=2, ensure_ascii=False, allow_nan=False) + "\n")
    else:
        for p, r in zip(args.csv, results):
            sys.stdout.write(
                f"bayescap: error: {_failure(p, r)}\n\n" if isinstance(r, BaseException) else format_text(r) + "\n"
            )
        sys.stdout.write(_batch_table(args.csv, results))
        print("table: with --out DIR the batch also writes DIR/summary.csv (pandas.read_csv)")
    for p, r in failed:
        print(f"bayescap: error: {_failure(p, r)}", file=sys.stderr)
    return 1 if failed else _strict_status(args, results)


def _fit_many_to_folder(args, datas, kw, scheduler, n_dask) -> int:
    """``--out DIR`` with several CSVs: DIR/<name>/result.json written as each chunk of sensors
    finishes, on the local pool (``--jobs``) or a Dask cluster (``--scheduler``/``--dask``); a rerun
    into the same DIR resumes (bayescap.batch.store)."""
    import json

    from bayescap.batch import fit_many
    from bayescap.batch.store import read_result

    client = cluster = None
    if scheduler is not None or n_dask is not None:
        from bayescap.batch.cluster import start_client

        client, cluster = start_client(scheduler, n_dask)
        if not quiet(args):
            print(f"bayescap: Dask dashboard: {client.dashboard_link}", file=sys.stderr)
    progress = progress_enabled(args)
    try:
        report = fit_many(
            datas,
            quality=args.quality,
            seed=args.seed,
            n_jobs=args.jobs,
            out=args.out,
            client=client,
            progress=progress,
            **kw,
        )
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    docs = []
    for p, r in zip(args.csv, report):
        if r["status"] != "error":
            try:
                docs.append(read_result(args.out, r["name"]))
                continue
            except (OSError, ValueError) as e:  # gone or spoilt since: this sensor's error
                r.update(status="error", error=f"cannot read {args.out}/{r['name']}/result.json back ({e})")
        docs.append({"input": p, "error": r["error"]})
    if args.json:
        sys.stdout.write(json.dumps(docs, indent=2, ensure_ascii=False, allow_nan=False) + "\n")
    elif not quiet(args):
        sys.stdout.write(_folder_table(args.csv, report, docs))
        print(f"table: {Path(args.out) / 'summary.csv'} (pandas.read_csv; 'bayescap summary DIR' rebuilds it)")
    failed = [(p, r) for p, r in zip(args.csv, report) if r["status"] == "error"]
    for p, r in failed:
        print(f"bayescap: error: {p}: {r['error']}", file=sys.stderr)
    if failed:
        return 1
    unconverged = [d for d in docs if not d.get("diagnostics", {}).get("converged")]
    if getattr(args, "strict", False) and unconverged:
        print(f"bayescap: {len(unconverged)} of {len(docs)} result(s) NOT CONVERGED (--strict)", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def _summary_cell(s) -> str:
    """``median [95 % interval]`` of a summary, or its limit alone (``> 1.2e+07 (95 % lower limit)``)
    for a quantity the data do not determine."""
    lim = s.get("limit")
    if lim:
        return f"{'<' if lim['kind'] == 'upper' else '>'} {lim['value']:.4g} ({100 * lim['level']:g} % {lim['kind']} limit)"
    lo, hi = s["ci95"]
    return f"{s['median']:.4g} [{lo:.4g}, {hi:.4g}]"


def _folder_table(paths, report, docs) -> str:
    """One line per CSV from the written results: its folder, method, convergence, K and capacity."""
    q = _summary_cell

    n_res = sum(r["status"] == "resumed" for r in report)
    lines = [
        f"batch summary ({len(paths)} CSVs, {n_res} found done and not refitted): median [95 % interval]",
        "csv | result | method | converged | conversion_gain_e_per_dn | capacity_bits",
    ]
    for p, r, d in zip(paths, report, docs):
        if r["status"] == "error":
            lines.append(f"{p} | error | - | - | - | -")
            continue
        dg = d.get("diagnostics", {})
        cap = d.get("derived", {}).get("capacity_bits")
        lines.append(
            f"{p} | {r['name']}/result.json | {dg.get('method', 'mcmc')} | {'yes' if dg.get('converged') else 'NO'} | "
            f"{q(d['parameters']['conversion_gain_e_per_dn'])} | {q(cap) if cap else 'n/a'}"
        )
    return "\n".join(lines) + "\n"


def _batch_table(paths, results) -> str:
    """One line per CSV: method, convergence, K and capacity with 95 % intervals (limits alone)."""
    q = _summary_cell

    lines = [
        f"batch summary ({len(paths)} CSVs): median [95 % interval]",
        "csv | method | converged | conversion_gain_e_per_dn | capacity_bits",
    ]
    for p, r in zip(paths, results):
        if isinstance(r, BaseException):
            lines.append(f"{p} | error | - | - | -")
            continue
        dg = r.diag
        der = r.derived_summary()
        cap = q(der["capacity_bits"]) if "capacity_bits" in der else "n/a"
        lines.append(
            f"{p} | {dg.get('method', 'mcmc')} | {'yes' if dg.get('converged') else 'NO'} | "
            f"{q(r.parameter_summary()['conversion_gain_e_per_dn'])} | {cap}"
        )
    return "\n".join(lines) + "\n"


def _scene_from_args(args, data):
    """A Scene from --scene / --scene-exposure-s / --temperature-c, or None for the default."""
    from bayescap.api import default_scene
    from bayescap.posterior import Scene

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
    t_c = spec.get("temperature_c")
    if t_c is not None and not (math.isfinite(t_c) and t_c <= _MAX_SCENE_TEMPERATURE_C):
        # before the fit: 2^(ΔT/6 °C) of an absurd temperature overflows after it
        raise InputError(
            f"scene temperature {t_c:g} °C is implausible for a working sensor (above {_MAX_SCENE_TEMPERATURE_C:g} °C)"
        )
    if not spec:
        return None
    base = default_scene(data)
    t = spec.get("exposure_s", base.exposure_time_s)
    temp = spec.get("temperature_c")
    ref = data.metadata.get("temperature_c")
    src = "--scene" if args.scene else ("--scene-exposure-s" if "exposure_s" in spec else base.source)
    try:  # Scene checks the exposure time and the temperature
        scene = Scene(
            exposure_time_s=t, source=src, temperature_c=temp, reference_temperature_c=ref if temp is not None else None
        )
    except ValueError as e:
        raise InputError(str(e)) from None
    if temp is not None and ref is None:
        raise InputError(
            f"{data.source}: a scene temperature needs the measurement's temperature: add "
            "'# temperature_c: <°C>' to the CSV"
        )
    return scene
