"""The bundled Basler CSV corrupted many ways, each run through ``bayescap fit --quality fast``.

    python benchmarks/corrupt_inputs.py [--seed 0] [--cells 60] [--include-slow] [--no-faults]

Every variant must either fit (exit 0) or be refused with one line naming the file (exit 2); a
traceback (an exception through ``bayescap.cli.main``), a RuntimeWarning, more than one line of error
or a modified input is listed as a defect, and the script exits 1 if there is one. Variants: ``cells``
random single cells (a bad token, or the value scaled by 10⁻¹²…10¹², negated, ...; ``--seed`` picks
them), each column dropped / zero / empty, structural ones (BOM, CRLF, tabs, rows cut or doubled, ...)
and metadata out of range. ``--include-slow`` adds the two that fit correctly but take ~2 minutes
each (dark variance 0 on every row: the exact rounding terms at read noise 10⁻⁴ e⁻).

Issue 48's families: subnormal and implausibly small values, cells past the csv module's limit,
metadata given twice or implausible, repeated rows, and the bundled simulated phone sensor cut to
its mostly saturated rows; in the subnormal, repeated-row and saturated families
(:data:`MUST_REFUSE`) a fit is a defect, since those tables give tight, wrong intervals. The fault family (:func:`fault_checks`, subprocesses; skip it
with ``--no-faults``) writes under ``ulimit -f``, kills a run during ``--out`` and runs again, runs
two batches on one folder, kills a ``--jobs 2`` parent, makes batch results unwritable and
outputs land on inputs: a crash, a leftover temporary file or worker, an input overwritten or more
than one line of error is a defect.

In-process (``cli.main``), so a variant costs what its fit costs. Writes
``benchmarks/results/corrupt_inputs.md``: how many variants fitted, how many were refused, and every
defect. ``tests/test_input_corruption.py`` keeps a fixed ~110 variants of this kind."""

import argparse
import contextlib
import io
import random
import sys
import tempfile
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
OUT = ROOT / "benchmarks" / "results" / "corrupt_inputs.md"

from _machine import describe_machine, emit  # noqa: E402

from bayescap import cli  # noqa: E402

BAD = [
    "abc",
    "",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "-1",
    "0",
    "1e308",
    "-0",
    "1e-320",
    " 5 ",
    "٣",
    "0x10",
    "1e999",
    "None",
    "true",
    "5e",
    "--3",
    "1_000",
]
SCALES = [1e6, 1e-6, -1, 0.5, 2, 1e12, 1e-12, 1 + 1e-9]
METADATA = [
    "# adc_bits: twelve",
    "# adc_bits: 0",
    "# adc_bits: 64",
    "# adc_bits: 8",
    "# adc_bits: 1.5",
    "# pixel_pitch_um: -3",
    "# pixel_pitch_um: 0",
    "# pixel_pitch_um: nan",
    "# width_px: 1e9",
    "# width_px: 0",
    "# f_number: 0",
    "# f_number: -2",
    "# fill_factor: 2",
    "# fill_factor: 0",
    "# black_level_dn: nan",
    "# black_level_dn: 1e6",
    "# wavelength_nm: 0",
    "# crosstalk_sigma_px: -1",
    "# crosstalk_sigma_px: 1e6",
    "# n_frames: 0",
    "# analog_gain: x",
    "#adc_bits 12",
    "# : 5",
    "# temperature_c: -300",
    "# channel: 7",
]
SLOW = ("column dark_temporal_var_dn2 all '0'", "every dark variance 0")


def variants(text, rng, n_cells):
    """{name: CSV text} of the corruptions (every family's, :func:`families`)."""
    return {k: v for fam in families(text, rng, n_cells).values() for k, v in fam.items()}


def families(text, rng, n_cells, phone_text=None):
    """{family: {name: CSV text}} of the corruptions."""
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    meta, header = lines[:k], lines[k].split(",")
    rows = [ln.split(",") for ln in lines[k + 1 :] if ln.strip()]

    def build(h, rs, m=meta, sep=",", eol="\n"):
        return eol.join(m + [sep.join(h)] + [sep.join(r) for r in rs]) + eol

    def col(j, value):
        return [r[:j] + [value] + r[j + 1 :] for r in rows]

    fam = {}
    out = fam["random single cells"] = {}
    for _ in range(n_cells):
        rs = [list(r) for r in rows]
        i, j = rng.randrange(len(rs)), rng.randrange(len(header))
        v = rs[i][j]
        v = rng.choice(BAD) if rng.random() < 0.5 or not v.strip() else repr(float(v) * rng.choice(SCALES))
        rs[i][j] = v
        out[f"row {i + 1} {header[j]}={v!r}"] = build(header, rs)
    out = fam["columns dropped, zero or empty"] = {}
    for j, c in enumerate(header):
        out[f"column {c} dropped"] = build(header[:j] + header[j + 1 :], [r[:j] + r[j + 1 :] for r in rows])
        out[f"header {c} dropped, not the data"] = build(header[:j] + header[j + 1 :], rows)
        out[f"column {c} all '0'"] = build(header, col(j, "0"))
        out[f"column {c} all empty"] = build(header, col(j, ""))
    out = fam["structure"] = {}
    out.update(
        {
            "empty file": "",
            "header only": build(header, []),
            "one row": build(header, rows[:1]),
            "two rows": build(header, rows[:2]),
            "BOM": "\ufeff" + build(header, rows),
            "CRLF": build(header, rows, eol="\r\n"),
            "tabs": build(header, rows, sep="\t"),
            "duplicate header column": build(header + ["mean_dn"], [r + ["1"] for r in rows]),
            "extra text column": build(header + ["comment"], [r + ["hello"] for r in rows]),
            "row too long": build(header, rows[:5] + [rows[5] + ["1"]] + rows[6:]),
            "row too short": build(header, rows[:5] + [rows[5][:-3]] + rows[6:]),
            "duplicated rows": build(header, rows + rows),
            "reversed rows": build(header, rows[::-1]),
            "binary": "\x00\x01\x02garbage\xff",
            "header upper case": build([h.upper() for h in header], rows),
            "every dark variance 0": build(header, col(header.index("dark_temporal_var_dn2"), "0")),
            "n_pixels 2 everywhere": build(header, col(header.index("n_pixels"), "2")),
        }
    )
    out = fam["metadata"] = {}
    for m in METADATA:
        out[f"metadata {m!r}"] = build(header, rows, meta + [m])
    fam.update(hostile_families(meta, header, rows, build, rng))
    if phone_text is not None:
        fam["mostly saturated tables"] = saturated_variants(phone_text)
    return fam


def hostile_families(meta, header, rows, build, rng):
    """Issue 48's hostile tables: subnormal and implausibly small values, cells past the csv
    module's limit, metadata given twice or implausible, rows repeated."""
    fam = {}
    out = fam["subnormal or implausible values"] = {}
    for j, c in enumerate(header):
        for v in ("4e-320", "-1e-310", "5e-324"):
            i = rng.randrange(len(rows))
            rs = [list(r) for r in rows]
            rs[i][j] = v
            out[f"row {i + 1} {c}={v}"] = build(header, rs)
    t = header.index("exposure_time_s")
    for f in (1e-300, 1e-15, 1e-310):
        out[f"every exposure time x {f:g}"] = build(
            header, [r[:t] + [repr(float(r[t]) * f)] + r[t + 1 :] for r in rows]
        )
    out = fam["oversized cells"] = {}
    for n in (131_073, 1_000_000, 10_000_000):
        for j in (0, 1, len(header) - 1):
            rs = [list(r) for r in rows]
            rs[3][j] = "1" * n
            out[f"row 4 {header[j]}: a {n:,}-character cell"] = build(header, rs)
        out[f"a {n:,}-character metadata line"] = build(header, rows, meta + ["# sensor: " + "x" * n])
    out = fam["metadata twice or implausible"] = {}
    plain = [m for m in meta if not m.startswith(("# width_px", "# height_px", "# pixel_pitch_um", "# adc_bits"))]
    for key, a, b in (
        ("adc_bits", "10", "16"),
        ("adc_bits", "12", "12.0"),
        ("pixel_pitch_um", "2.2", "3.45"),
        ("width_px", "640", "1280"),
        ("sensor", "A", "B"),
        ("black_level_dn", "64", "0"),
    ):
        out[f"{key}: {a} then {b}"] = build(header, rows, plain + [f"# {key}: {a}", f"# {key}: {b}"])
    for m in ("# width_px: 1e30", "# height_px: 1e7", "# pixel_pitch_um: 1e4", "# width_px: 1000001"):
        out[f"metadata {m!r}"] = build(header, rows, plain + [m])
    for m in ("# sensor: cam\x1b[2J\x07", "# sensor: a\x00b", "# manufacturer: \x1b]0;title\x07"):
        out[f"metadata {m!r} (control characters)"] = build(header, rows, meta + [m.encode().decode("unicode_escape")])
    out = fam["repeated rows"] = {}
    for i in (0, 5, len(rows) - 1):
        for k in (1, 10, 300):
            out[f"row {i + 1} repeated {k} more times"] = build(header, rows + [rows[i]] * k)
    for k in (2, 3, 10):
        out[f"the table repeated {k} times"] = build(header, rows * k)
    out["the table repeated, shuffled"] = build(header, rng.sample(rows + rows, 2 * len(rows)))
    return fam


def saturated_variants(text):
    """Tables of the bundled simulated phone sensor cut to its mostly saturated rows
    (frac_saturated > 0.5): each must be refused (it was fitted to a tight, wrong K)."""
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    meta, header = lines[:k], lines[k]
    j = header.split(",").index("frac_saturated")
    rows = [ln for ln in lines[k + 1 :] if ln.strip()]
    sat = [ln for ln in rows if float(ln.split(",")[j]) > 0.5]
    out = {}
    for n in range(2, len(sat) + 1):
        out[f"the {n} most saturated rows (all > 0.5)"] = "\n".join(meta + [header] + sat[-n:]) + "\n"
    out["the mostly saturated rows, less the fully clipped ones but one"] = (
        "\n".join(meta + [header] + [ln for ln in sat if float(ln.split(",")[j]) < 1.0] + sat[-1:]) + "\n"
    )
    return out


#: families whose every variant must be refused: fitting them gives a tight, wrong interval
MUST_REFUSE = ("subnormal or implausible values", "repeated rows", "mostly saturated tables")


def run(path):
    """(exit code or the exception, stderr lines, RuntimeWarnings) of ``bayescap fit PATH --quality fast``."""
    out, err = io.StringIO(), io.StringIO()
    with (
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
        warnings.catch_warnings(record=True) as caught,
    ):
        warnings.simplefilter("always", RuntimeWarning)
        try:
            code = cli.main(["fit", str(path), "--quality", "fast", "--seed", "1"])
        except SystemExit as e:
            code = e.code
        except Exception as e:  # noqa: BLE001 - a traceback is what this looks for
            code = f"{type(e).__name__}: {e}"
    runtime = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    return code, err.getvalue().strip().splitlines(), runtime


# ------------------------------------------------------------------------- faults while writing


def _cli(args, *, limit=None, timeout=600, **kw):
    """``python -m bayescap ARGS`` in a subprocess (optionally under ``ulimit -f LIMIT`` bytes)."""
    import os
    import subprocess

    def pre():
        if limit is not None:
            import resource

            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))

    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "bayescap", *map(str, args)]
    if kw.get("popen"):
        return subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, preexec_fn=pre)


def _children(pid):
    import os

    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                st = Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(st[1]) == pid and st[0] != "Z":
                out.append(int(d))
    return out


def _alive(pid):
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _twins(folder):
    return sorted(p.name for p in Path(folder).iterdir() if p.name.startswith("."))


def fault_checks(tmp):
    """(name, None or why it is a defect) of each fault: a file-size limit during ``--out`` and
    ``FitResult.save``, ``kill -9`` during ``--out``, two batches on one folder, a pool's parent
    killed, batch results that cannot be written, outputs over inputs, LAPACK on stdout."""
    import os
    import signal
    import subprocess

    basler = ROOT / "data" / "emva1288_basler_ccd12.csv"
    fit = ["fit", basler, "--quality", "fast", "--seed", "1", "--no-progress"]
    for limit in (50_000, 500_000, 3_000_000):
        d = tmp / f"fsize{limit}"
        d.mkdir()
        r = _cli([*fit, "--out", d / "o"], limit=limit)
        err = r.stderr.strip().splitlines()
        why = None
        if r.returncode != 1 or len(err) != 1 or "cannot write" not in err[0]:
            why = f"exit {r.returncode}, stderr {err[-1:]}"
        elif os.listdir(d):
            why = f"left {os.listdir(d)}"
        yield f"fit --out under ulimit -f {limit} bytes", why
    d = tmp / "save"
    d.mkdir()
    code = (
        "import resource, bayescap\n"
        f"r = bayescap.fit({str(basler)!r}, seed=1, quality='fast')\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, resource.RLIM_INFINITY))\n"
        f"try:\n    r.save({str(d / 'r.nc')!r})\nexcept OSError as e:\n    print('OSError', e.errno)\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True
    )
    ok = r.returncode == 0 and "OSError 27" in r.stdout and not os.listdir(d)
    yield "FitResult.save under ulimit -f 300 kB", None if ok else f"exit {r.returncode}, left {os.listdir(d)}"

    d = tmp / "kill9"
    d.mkdir()
    p = _cli([*fit, "--out", d / "o"], popen=True)
    t0, seen = time.time(), False
    while p.poll() is None and time.time() - t0 < 600:
        if any(n.endswith(".tmp") for n in os.listdir(d)):
            p.kill()
            seen = True
            break
        time.sleep(0.02)
    p.wait()
    left = _twins(d)
    code = f"from bayescap.io.atomic import write_dir_atomically as w; w({str(d / 'o')!r}, lambda t: (t / 'a').write_text('x'))"
    subprocess.run([sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=str(ROOT)), check=True)
    why = None if not _twins(d) else f"twins left after the next run: {_twins(d)}"
    yield (
        f"kill -9 during --out ({'killed while writing, left ' + str(left) if seen else 'finished before the kill'}), then a run",
        why,
    )

    from bayescap.batch import gpixel_sensors
    from bayescap.io.ptc_csv import write_ptc_csv

    d = tmp / "batch"
    d.mkdir()
    datas, _ = gpixel_sensors(n_max=12, seed=4)
    csvs = []
    for i, x in enumerate(datas):
        csvs.append(d / f"roi{i}.csv")
        write_ptc_csv(x, csvs[-1])
    out = d / "out"
    first = _cli(["fit", *csvs, "--out", out, "--quality", "fast", "--seed", "1", "--no-progress"], popen=True)
    t0 = time.time()
    while not out.exists() and first.poll() is None and time.time() - t0 < 120:
        time.sleep(0.05)
    second = _cli(["fit", *csvs[:2], "--out", out, "--quality", "fast", "--seed", "2", "--no-progress"])
    rc1 = first.wait()
    err = second.stderr.strip().splitlines()
    ok = rc1 == 0 and second.returncode == 2 and len(err) == 1 and "another batch" in err[0]
    yield (
        "two batches on one --out at once",
        None if ok else f"first exit {rc1}, second exit {second.returncode} {err[-1:]}",
    )

    for sig in (signal.SIGTERM, signal.SIGKILL):
        parent = _cli(
            ["fit", *csvs, "--out", d / f"pool{int(sig)}", "--jobs", "2", "--quality", "fast", "--seed", "1"],
            popen=True,
        )
        t0, kids = time.time(), []
        while len(kids) < 2 and parent.poll() is None and time.time() - t0 < 120:
            kids = _children(parent.pid)
            time.sleep(0.1)
        parent.send_signal(sig)
        parent.wait()
        t0 = time.time()
        while any(_alive(k) for k in kids) and time.time() - t0 < 15:
            time.sleep(0.1)
        alive = [k for k in kids if _alive(k)]
        for k in alive:
            os.kill(k, signal.SIGKILL)
        why = None if len(kids) >= 2 and not alive else f"{len(kids)} workers seen, {len(alive)} alive 15 s after"
        yield f"--jobs 2, the parent sent {signal.Signals(sig).name}", why

    out = d / "wfail"
    (out / "roi1" / "result.json").mkdir(parents=True)
    long = [d / "l1", d / "l2"]
    for x in long:
        x.mkdir()
        (x / ("y" * 250 + ".csv")).write_bytes(csvs[0].read_bytes())
    r = _cli(
        ["fit", *[x / ("y" * 250 + ".csv") for x in long], *csvs[:3], "--out", out, "--quality", "fast", "--seed", "1"]
    )
    err = r.stderr.strip().splitlines()
    written = len([p for p in out.glob("*/result.json") if p.is_file()])
    ok = (
        r.returncode == 1
        and len(err) == 1
        and "roi1/result.json" in err[0]
        and written == 4
        and "Traceback" not in r.stderr
    )
    yield (
        "batch: names over 255 bytes after _2, a result.json that is a folder",
        None if ok else f"exit {r.returncode}, {written} written, {err[-1:]}",
    )

    lens = d / "L.csv"
    lens.write_text("frequency_cy_per_px,mtf\n0,1\n0.25,0.6\n0.5,0.3\n1,0.1\n")
    before = lens.read_bytes()
    edge = ROOT / "tests" / "data" / "slanted_edge" / "sfrmat3_v_edge_mono.tif"
    r = _cli(["mtf", edge, "--lens-mtf", lens, "--out", lens])
    ok = r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and lens.read_bytes() == before
    yield "mtf --lens-mtf L.csv --out L.csv", None if ok else f"exit {r.returncode}"
    x = d / "x.html"
    r = _cli(["datasheet", basler, "-o", x, "--json", x])
    ok = r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and not x.exists()
    yield "datasheet -o X --json X", None if ok else f"exit {r.returncode}"

    lines = basler.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    j = lines[k].split(",").index("exposure_time_s")
    body = [ln.split(",") for ln in lines[k + 1 :] if ln.strip()]
    sub = d / "subnormal.csv"
    sub.write_text(
        "\n".join(lines[: k + 1] + [",".join(c[:j] + [repr(float(c[j]) * 1e-310)] + c[j + 1 :]) for c in body]) + "\n"
    )
    r = _cli(["fit", sub, "--json", "--quality", "fast", "--seed", "1"])
    ok = r.returncode == 2 and r.stdout == "" and len(r.stderr.strip().splitlines()) == 1
    yield (
        "subnormal exposure times with --json: nothing on stdout",
        None if ok else f"exit {r.returncode}, stdout {r.stdout[:80]!r}",
    )


def _judge(family, name, path, code, lines, runtime, before):
    """None, or why the variant is a defect."""
    one_line = code == 2 and len(lines) == 1 and lines[0].startswith(f"bayescap: error: {path}")
    if not (code == 0 or one_line):
        return "not exit 0 nor one line naming the file with exit 2"
    if family in MUST_REFUSE and code == 0:
        return "fitted a table that must be refused"
    if (
        family == "metadata twice or implausible"
        and "twice" in name
        and code == 0
        and name.split(": ")[1].split(" then ")[0] != name.split(" then ")[1]
    ):
        return "took one of two different metadata values silently"
    if runtime:
        return "RuntimeWarning"
    if path.read_bytes() != before:
        return "input modified"
    return None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="picks the random cells (default 0)")
    ap.add_argument("--cells", type=int, default=60, help="random single-cell corruptions (default 60)")
    ap.add_argument("--include-slow", action="store_true", help="also the two ~2-minute variants")
    ap.add_argument("--no-faults", action="store_true", help="skip the fault family (subprocesses, ~5 minutes)")
    a = ap.parse_args(argv)
    text = (ROOT / "data" / "emva1288_basler_ccd12.csv").read_text(encoding="utf-8")
    phone = (ROOT / "data" / "simulated" / "sim_phone_1p75um_10bit.csv").read_text(encoding="utf-8")
    fams = families(text, random.Random(a.seed), a.cells, phone)
    defects, t0, skipped, counts = [], time.perf_counter(), 0, {}
    with tempfile.TemporaryDirectory() as tmp:
        k = 0
        for family, cases in fams.items():
            c = counts.setdefault(family, {"variants": 0, "fitted": 0, "refused": 0, "defects": 0})
            for name, body in cases.items():
                k += 1
                if name in SLOW and not a.include_slow:
                    skipped += 1
                    continue
                p = Path(tmp) / f"v{k}.csv"
                p.write_text(body, encoding="utf-8", errors="surrogateescape")
                before = p.read_bytes()
                t = time.perf_counter()
                code, lines, runtime = run(p)
                why = _judge(family, name, p, code, lines, runtime, before)
                print(
                    f"{time.perf_counter() - t:6.2f} s  exit {code}  {name[:60]:60s} {'DEFECT: ' + why if why else ''}",
                    flush=True,
                )
                c["variants"] += 1
                if why:
                    c["defects"] += 1
                    defects.append((family, name, why, code, [ln[:300] for ln in lines[:2]], runtime[:2]))
                else:
                    c["fitted" if code == 0 else "refused"] += 1
        if not a.no_faults:
            c = counts.setdefault(
                "faults while writing (subprocesses)", {"variants": 0, "fitted": 0, "refused": 0, "defects": 0}
            )
            for name, why in fault_checks(Path(tmp)):
                print(f"fault  {name[:70]:70s} {'DEFECT: ' + why if why else 'ok'}", flush=True)
                c["variants"] += 1
                if why:
                    c["defects"] += 1
                    defects.append(("faults", name, why, "-", [], []))
                else:
                    c["refused"] += 1
    wall = time.perf_counter() - t0
    cmd = (
        "python benchmarks/corrupt_inputs.py"
        + (f" --seed {a.seed}" if a.seed else "")
        + (f" --cells {a.cells}" if a.cells != 60 else "")
        + (" --include-slow" if a.include_slow else "")
        + (" --no-faults" if a.no_faults else "")
    )
    total = sum(c["variants"] for c in counts.values())
    L = [
        "# The bundled CSVs corrupted, through `bayescap fit --quality fast`; faults while writing",
        "",
        f"Generated by `{cmd}` in {wall:.0f} s; machine: {describe_machine()}.",
        "",
        f"{total} variants ({a.cells} random single cells, seed {a.seed}"
        + (f"; the {skipped} slow ones skipped: `--include-slow`" if skipped else "")
        + "). A defect is a traceback, a RuntimeWarning, more than one line of error, a modified input, "
        f"or, in the families {', '.join(MUST_REFUSE)}, a fit (those tables give a tight, wrong interval: "
        "they must be refused); in the fault family, a crash, a leftover temporary file or process, "
        "an output over an input, or more than one line of error.",
        "",
        "| family | variants | fitted (exit 0) | refused in one line (exit 2; faults: handled) | **defects** |",
        "|---|---|---|---|---|",
    ]
    L += [f"| {f} | {c['variants']} | {c['fitted']} | {c['refused']} | {c['defects']} |" for f, c in counts.items()]
    tot = {k: sum(c[k] for c in counts.values()) for k in ("variants", "fitted", "refused", "defects")}
    L += [f"| **all** | {tot['variants']} | {tot['fitted']} | {tot['refused']} | **{tot['defects']}** |", ""]
    if defects:
        L += ["| family | variant | why | exit | stderr | RuntimeWarnings |", "|---|---|---|---|---|---|"]
        L += [
            f"| {f} | {n} | {w} | {c} | {' / '.join(ln)} | {' / '.join(rt)} |".replace("\n", " ")
            for f, n, w, c, ln, rt in defects
        ]
    emit(L, OUT)
    return 1 if defects else 0


if __name__ == "__main__":
    sys.exit(main())
