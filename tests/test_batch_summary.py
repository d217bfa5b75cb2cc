"""A batch folder in one table (issue 49): ``DIR/summary.csv`` (and ``.parquet``) written by the
batch, one row per ``result.json``, loads with ``pandas.read_csv`` and gives back the JSON's
numbers; ``bayescap summary DIR`` rebuilds it; a limit is in its own columns."""

import json
import math
from pathlib import Path

import pandas as pd
import pytest

from bayescap.batch import fit_many, gpixel_sensors
from bayescap.cli import main

ROOT = Path(__file__).resolve().parents[1]
BASLER = str(ROOT / "data/emva1288_basler_ccd12.csv")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    datas, _ = gpixel_sensors(n_max=3, seed=3)
    out = tmp_path_factory.mktemp("batch") / "results"
    report = fit_many([*datas, BASLER], seed=5, out=out)
    assert all(r["status"] == "fitted" for r in report)
    return out, report


def _close(a, b):
    return (a is None and (b is None or (isinstance(b, float) and math.isnan(b)))) or a == b


def test_summary_csv_loads_with_pandas_and_matches_every_result_json(folder):
    out, report = folder
    df = pd.read_csv(out / "summary.csv")
    assert list(df["name"]) == sorted(r["name"] for r in report)
    for _, row in df.iterrows():
        doc = json.loads((out / row["name"] / "result.json").read_text())
        assert row["converged"] == doc["diagnostics"]["converged"] and row["method"] == doc["diagnostics"]["method"]
        assert row["input"] == doc["input"] and row["seed"] == doc["diagnostics"]["seed"]
        for group in ("parameters", "derived"):
            for q, s in doc[group].items():
                assert _close(s["median"], row[f"{q}_median"]), (row["name"], q)
                assert _close(s["ci95"][0], row[f"{q}_ci95_low"]) and _close(s["ci95"][1], row[f"{q}_ci95_high"])
                assert _close(s["ci68"][0], row[f"{q}_ci68_low"]) and _close(s["ci68"][1], row[f"{q}_ci68_high"])
                lim = s.get("limit")
                if lim:
                    assert row[f"{q}_limit"] == lim["kind"] and row[f"{q}_limit_value"] == lim["value"]
                elif f"{q}_limit" in row:
                    assert pd.isna(row[f"{q}_limit"])
    basler = df[df["name"] == "emva1288_basler_ccd12"].iloc[0]
    assert basler["dsnu_e_limit"] == "upper"  # the Basler's DSNU is an upper limit
    assert "metadata_defaults" in basler["flags"]


def test_summary_parquet_is_the_csv(folder):
    pytest.importorskip("pyarrow")
    out, _ = folder
    a, b = pd.read_csv(out / "summary.csv"), pd.read_parquet(out / "summary.parquet")
    assert list(a.columns) == list(b.columns) and len(a) == len(b)
    assert (a.isna() == b.isna()).all().all()
    for c in a.columns:
        x, y = a[c].dropna().tolist(), b[c].dropna().tolist()
        assert x == y, c


def test_bayescap_summary_rebuilds_the_files(folder, capsys):
    out, _ = folder
    before = (out / "summary.csv").read_bytes()
    (out / "summary.csv").unlink()
    (out / "summary.parquet").unlink(missing_ok=True)
    assert main(["summary", str(out)]) == 0
    assert (out / "summary.csv").read_bytes() == before
    assert "summary.csv" in capsys.readouterr().out


def test_bayescap_summary_of_a_folder_without_results_is_one_line(tmp_path, capsys):
    assert main(["summary", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "result.json" in err
    assert not (tmp_path / "summary.csv").exists()
