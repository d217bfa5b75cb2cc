"""Build the bundled photon-transfer CSVs in data/ (run from the repository root):

    python data/make_bundled_data.py

1. ``emva1288_basler_ccd12.csv``: the real EMVA 1288 reference set 001 (Basler CCD, 12 bit,
   CC BY-SA 3.0, Basler AG 2011) converted to the contract: the 50 full-frame pair rows of
   ``emva1288_refset001/ptc_pairs_fullframe.csv`` plus one row computed from the real 50-frame
   spatial stacks (64x64 centre crops, 5.16 ms) in ``tests/data/emva1288_basler/``, which
   carries the spatial variances (PRNU, DSNU).
2. ``simulated/*.csv``: three sensors simulated frame by frame by :mod:`bayescap.simulate`,
   each with its truth in ``*.truth.json``. They are simulations, never measurements.

The script is deterministic (fixed seeds); rerunning it reproduces the files byte for byte.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from bayescap.io.ptc_csv import atomic_write_text, write_ptc_csv
from bayescap.simulate import SensorTruth, simulate_ptc

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def basler():
    src = HERE / "emva1288_refset001" / "ptc_pairs_fullframe.csv"
    rows = list(csv.DictReader(open(src, newline="")))
    n = len(rows)
    cols = {
        "exposure_time_s": [float(r["texp_ns"]) * 1e-9 for r in rows],
        "mean_dn": [float(r["mean_DN"]) for r in rows],
        "temporal_var_dn2": [float(r["var_temporal_DN2"]) for r in rows],
        "dark_mean_dn": [float(r["dark_mean_DN"]) for r in rows],
        "dark_temporal_var_dn2": [float(r["dark_var_temporal_DN2"]) for r in rows],
        "n_pixels": [640 * 480] * n,
        "photons_per_pixel": [float(r["photons_per_pixel"]) for r in rows],
        "frac_saturated": [float(r["frac_saturated"]) for r in rows],
        "spatial_var_dn2": [np.nan] * n,
        "dark_spatial_var_dn2": [np.nan] * n,
        "n_frames": [np.nan] * n,
    }
    z = np.load(ROOT / "tests" / "data" / "emva1288_basler" / "frames_center_crops.npz")
    b = z["spatial_bright_stack"].astype(float)
    d = z["spatial_dark_stack"].astype(float)

    def pair(a, c):
        diff = a - c
        return 0.5 * (a.mean() + c.mean()), 0.5 * (np.mean(diff * diff) - diff.mean() ** 2)

    m, v = pair(b[0], b[1])
    dm, dv = pair(d[0], d[1])
    extra = {
        "exposure_time_s": float(z["spatial_bright_texp_ns"]) * 1e-9,
        "mean_dn": m,
        "temporal_var_dn2": v,
        "dark_mean_dn": dm,
        "dark_temporal_var_dn2": dv,
        "n_pixels": b.shape[1] * b.shape[2],
        "photons_per_pixel": float(z["spatial_bright_photons_per_pixel"]),
        "frac_saturated": float(np.mean(b[:2] >= 4095)),
        "spatial_var_dn2": float(b.mean(axis=0).var(ddof=1)),
        "dark_spatial_var_dn2": float(d.mean(axis=0).var(ddof=1)),
        "n_frames": b.shape[0],
    }
    for k, val in extra.items():
        cols[k].append(val)
    md = {
        "sensor": "Basler CCD 640x480 12 bit (EMVA 1288 reference set 001)",
        "manufacturer": "Basler",
        "adc_bits": 12,
        "width_px": 640,
        "height_px": 480,
        "channel": "mono",
        "source": "EMVA1288/datasets EMVA1288_ReferenceSet_001_CCD_12Bit (CC BY-SA 3.0, Basler AG 2011)",
        "note": (
            "rows 1-50 full-frame pairs; row 51 the 64x64 centre crop of the 50-frame spatial stacks "
            "(gives PRNU and DSNU)"
        ),
    }
    write_ptc_csv({k: np.asarray(v, float) for k, v in cols.items()}, HERE / "emva1288_basler_ccd12.csv", metadata=md)


SIMULATED = {
    # ADC clips before the well; spatial stacks every 10th level
    "sim_phone_1p75um_10bit": dict(
        truth=SensorTruth(
            conversion_gain_e_per_dn=4.0,
            read_noise_e=3.5,
            full_well_e=8000.0,
            dark_current_e_per_s=25.0,
            quantum_efficiency=0.5,
            prnu_frac=0.010,
            dsnu_e=2.0,
            adc_bits=10,
            black_level_dn=64.0,
        ),
        md={
            "sensor": "simulated phone sensor 1.75 um (10 bit)",
            "manufacturer": "simulated",
            "temperature_c": 25.0,
            "pixel_pitch_um": 1.75,
            "width_px": 3264,
            "height_px": 2448,
        },
        kw=dict(spatial_frames=16, spatial_every=10),
        seed=101,
    ),
    # the well clips before the read-out
    "sim_industrial_3p45um_12bit": dict(
        truth=SensorTruth(
            conversion_gain_e_per_dn=3.0,
            read_noise_e=2.3,
            full_well_e=10500.0,
            dark_current_e_per_s=5.0,
            quantum_efficiency=0.7,
            prnu_frac=0.005,
            dsnu_e=1.5,
            full_well_spread_frac=0.003,
            adc_bits=12,
            black_level_dn=64.0,
        ),
        md={
            "sensor": "simulated industrial sensor 3.45 um (12 bit)",
            "manufacturer": "simulated",
            "temperature_c": 25.0,
            "pixel_pitch_um": 3.45,
            "width_px": 2448,
            "height_px": 2048,
        },
        kw=dict(spatial_frames=16, spatial_every=10),
        seed=202,
    ),
    # never reaches saturation: the full well can only be bounded from below
    "sim_scientific_6p5um_16bit_unsaturated": dict(
        truth=SensorTruth(
            conversion_gain_e_per_dn=0.5,
            read_noise_e=1.2,
            full_well_e=30000.0,
            dark_current_e_per_s=0.5,
            quantum_efficiency=0.8,
            adc_bits=16,
            black_level_dn=100.0,
        ),
        md={
            "sensor": "simulated scientific sensor 6.5 um (16 bit), unsaturated series",
            "manufacturer": "simulated",
            "temperature_c": 25.0,
            "pixel_pitch_um": 6.5,
            "width_px": 2048,
            "height_px": 2048,
        },
        kw=dict(max_fraction=0.7),
        seed=303,
    ),
}


def simulated():
    out = HERE / "simulated"
    for name, spec in SIMULATED.items():
        truth = spec["truth"]
        simulate_ptc(
            truth, seed=spec["seed"], path=out / f"{name}.csv", metadata=spec["md"], shape=(100, 100), **spec["kw"]
        )
        atomic_write_text(
            out / f"{name}.truth.json",
            json.dumps(
                {
                    "name": name,
                    "seed": spec["seed"],
                    "truth": truth.to_dict(),
                    "simulation": {k: v for k, v in spec["kw"].items()},
                    "roi_px": [100, 100],
                    "note": "simulated with bayescap.simulate; not a measurement",
                },
                indent=2,
            )
            + "\n",
        )


def s_shaped():
    """An 8-bit camera with an S-shaped response (the non-linear zoo's nl_s_shape_8bit_ph: frames
    from bayescap.validation.framesim), for the README's "Real sensors" example."""
    import shutil
    import tempfile

    from bayescap.validation.zoo_nonlinear import ensure_csvs, nonlinear_zoo, scored_truths

    zs = next(z for z in nonlinear_zoo() if z.name == "nl_s_shape_8bit_ph")
    name = "sim_s_shape_8bit"
    with tempfile.TemporaryDirectory() as tmp:
        path, _ = ensure_csvs(zs, Path(tmp))
        shutil.copyfile(path, HERE / "simulated" / f"{name}.csv")
    r = zs.sensor.response
    atomic_write_text(
        HERE / "simulated" / f"{name}.truth.json",
        json.dumps(
            {
                "name": name,
                "seed": zs.seed,
                "truth": {p: v[0] for p, v in scored_truths(zs).items()},
                "response": {"kind": r.kind, "strength": r.strength, "ref_e": r.ref_e},
                "zoo_sensor": zs.name,
                "note": "simulated frame by frame with bayescap.validation.framesim; not a measurement",
            },
            indent=2,
        )
        + "\n",
    )


if __name__ == "__main__":
    basler()
    simulated()
    s_shaped()
    print(
        "wrote", sorted(p.name for p in HERE.glob("*.csv")), sorted(p.name for p in (HERE / "simulated").glob("*.csv"))
    )
