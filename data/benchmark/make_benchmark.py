"""Build the benchmark photon-transfer CSVs in data/benchmark/ (run from the repository root):

    python data/benchmark/make_benchmark.py

Everything written here is SIMULATED with :mod:`bayescap.simulate`; nothing is a measurement.

1. ``M*_*.csv``: the five sensors of Table 2 of Tisse, Guichard & Cao (SPIE 2008). Every parameter
   comes from a published source named in ``SOURCES`` and nothing else: Table 1 of the paper for the
   pitch (``data/paper_table1_pixel_parameters.csv``; the 2.80 µm pixel interpolated linearly in
   pitch between the 2.20 and 2.90 µm rows) for sensitivity, full well, dark current and PRNU, and
   one measured small-pixel sensor of the compiled table (``sensor_specs/``, row ``imx900_lcg``)
   for what Table 1 does not give (read noise, DSNU). No per-manufacturer factor: nothing published
   tells M1 from M2, so two sensors of the same pitch share their parameters and differ only by
   resolution and random seed. No crosstalk: none is published, and the paper's own simulations
   assume none. The comparison falls where these inputs put it; nothing here is chosen to reproduce
   a result of the paper's Section 4.
2. ``datasheet/*.csv``: four real sensors *built from datasheet values*: a PTC simulated from the
   published parameters in ``sensor_specs/sensor_characterization_table.csv`` (copied from the
   shared compiled table, with its README). The parameters are published; the PTC is not.

Each CSV carries ``photons_per_pixel`` and ``exposure_lux_s`` when the sensitivity is known:
``exposure_lux_s = photons_per_pixel / (4090.7 · P²)``, Eq. 4 at 555 nm (monochromatic
equivalent, K_m = 683 lm/W, E = h·c/λ). A ``*.truth.json`` beside each CSV holds the truth.

The script is deterministic (fixed seeds); rerunning it reproduces the files byte for byte.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from bayescap.io.ptc_csv import atomic_write_text, write_ptc_csv
from bayescap.physics.photometry import photons_per_lux_s_um2
from bayescap.physics.table1 import load_table1
from bayescap.simulate import SensorTruth, simulate_ptc

HERE = Path(__file__).resolve().parent
PHOTONS_PER_LUX_S_UM2 = float(photons_per_lux_s_um2(wavelength_nm=555.0))  # 4090.7

SIMULATED_NOTE = "SIMULATED with bayescap.simulate; not a measurement"

#: Table 2 of the paper: designation -> (manufacturer, pitch µm, width, height, optical format)
TABLE2 = {
    "M2_2.80um": ("M2", 2.80, 1600, 1200, '1/3"'),
    "M2_2.20um": ("M2", 2.20, 2056, 1544, '1/3.2"'),
    "M1_2.20um": ("M1", 2.20, 2048, 1536, '1/3.2"'),
    "M2_1.75um": ("M2", 1.75, 2048, 1536, '1/4"'),
    "M1_1.75um": ("M1", 1.75, 2048, 1536, '1/4"'),
}

#: the compiled table's row that supplies what Table 1 does not give (read noise, DSNU): the only
#: row with a pitch inside Table 2's 1.75-2.80 µm range that was measured (EMVA 1288 lab report,
#: confidence "medium"), at 0 dB analog gain
GENERATION_ROW = "imx900_lcg"

#: where each stand-in parameter comes from (written into each truth.json and the README)
SOURCES = {
    "sensitivity_e_per_lux_s": "Table 1, sensitivity at the pitch",
    "full_well_e": "Table 1, middle of the printed full-well range at the pitch",
    "dark_current_e_per_s": "Table 1, dark current at 25 C (Cohen pixels: the 60 C value scaled by the 6 C law)",
    "prnu_frac": "Table 1, the printed PRNU bound (as in the paper's own Fig. 2(b) simulations)",
    "quantum_efficiency": "sensitivity / (4090.7 photons/(lux.s.um^2) x pitch^2) (Eq. 4 at 555 nm)",
    "read_noise_e": f"sensor_specs/sensor_characterization_table.csv row {GENERATION_ROW}, read_noise_e",
    "dsnu_e": f"sensor_specs/sensor_characterization_table.csv row {GENERATION_ROW}, dsnu_e",
    "crosstalk": "none: not published for these sensors; the paper's simulations assume none",
    "manufacturer": "no per-manufacturer difference: none is published",
}
SEEDS = {"M2_2.80um": 2801, "M2_2.20um": 2202, "M1_2.20um": 2201, "M2_1.75um": 1752, "M1_1.75um": 1751}

ADC_BITS = 12  # RAW bit depth (not given by the paper; see README)
BLACK_DN = 64.0
ADC_HEADROOM = 1.03  # the ADC clips 3 % above the mean full well: the well clips first
SIM = dict(n_levels=40, shape=(100, 100), spatial_frames=16, spatial_every=8)


def table1_at(pitch_um: float) -> dict:
    """Table 1 values at ``pitch_um``: the row itself, or linear interpolation in pitch between
    the two neighbouring rows (full well: the middle of the printed range; dark current at 25 °C;
    PRNU: the printed upper bound)."""
    rows = sorted(load_table1(), key=lambda s: s.pitch_um)
    pitches = np.array([r.pitch_um for r in rows])

    def interp(get):
        return float(np.interp(pitch_um, pitches, [get(r) for r in rows]))

    return {
        "sensitivity_e_per_lux_s": interp(lambda r: r.sensitivity_e_per_lux_s),
        "full_well_e": interp(lambda r: r.full_well_mid_e),
        "dark_current_e_per_s": interp(lambda r: r.dark_current_e_per_s(25.0)),
        "prnu_max_frac": interp(lambda r: r.prnu_max_frac),
        "interpolated": bool(not np.any(np.isclose(pitches, pitch_um))),
    }


def _write(name, truth: SensorTruth, md: dict, seed: int, out: Path, *, pitch_um, calibrated: bool, provenance: dict):
    d = simulate_ptc(truth, seed=seed, metadata=md, **SIM)
    cols = {
        c: getattr(d, c)
        for c in (
            "exposure_time_s",
            "mean_dn",
            "temporal_var_dn2",
            "dark_mean_dn",
            "dark_temporal_var_dn2",
            "n_pixels",
            "photons_per_pixel",
            "spatial_var_dn2",
            "dark_spatial_var_dn2",
            "n_frames",
            "frac_saturated",
        )
    }
    if calibrated:
        cols["exposure_lux_s"] = np.asarray(d.photons_per_pixel) / (PHOTONS_PER_LUX_S_UM2 * pitch_um**2)
    else:  # the quantum efficiency is not published: no photon or lux calibration in the file
        del cols["photons_per_pixel"]
    write_ptc_csv({k: np.asarray(v, float) for k, v in cols.items()}, out / f"{name}.csv", metadata=md)
    atomic_write_text(
        out / f"{name}.truth.json",
        json.dumps(
            {
                "name": name,
                "seed": seed,
                "truth": truth.to_dict(),
                "simulation": {k: list(v) if isinstance(v, tuple) else v for k, v in SIM.items()},
                "provenance": provenance,
                "note": SIMULATED_NOTE,
            },
            indent=2,
        )
        + "\n",
    )


def generation_noise() -> dict:
    """Read noise and DSNU (e⁻) of :data:`GENERATION_ROW` in the compiled sensor table."""
    row = next(r for r in _spec_rows() if r["id"] == GENERATION_ROW)
    return {"read_noise_e": float(row["read_noise_e"]), "dsnu_e": float(row["dsnu_e"])}


def table2_truth(pitch_um: float) -> SensorTruth:
    """The stand-in truth at ``pitch_um``: Table 1 at the pitch, the generation's read noise and DSNU."""
    t1 = table1_at(pitch_um)
    noise = generation_noise()
    sens, fw = t1["sensitivity_e_per_lux_s"], t1["full_well_e"]
    return SensorTruth(
        conversion_gain_e_per_dn=round(ADC_HEADROOM * fw / (2**ADC_BITS - 1 - BLACK_DN), 4),
        read_noise_e=noise["read_noise_e"],
        full_well_e=round(fw, 1),
        dark_current_e_per_s=round(t1["dark_current_e_per_s"], 3),
        quantum_efficiency=round(sens / (PHOTONS_PER_LUX_S_UM2 * pitch_um**2), 4),
        prnu_frac=round(t1["prnu_max_frac"], 5),
        dsnu_e=noise["dsnu_e"],
        full_well_spread_frac=0.005,
        adc_bits=ADC_BITS,
        black_level_dn=BLACK_DN,
    )


def table2_sensors(out: Path = HERE):
    for name, (manu, pitch, w, h, fmt) in TABLE2.items():
        truth = table2_truth(pitch)
        sens = table1_at(pitch)["sensitivity_e_per_lux_s"]
        md = {
            "sensor": f"{name} (simulated, Table 2 of Tisse et al. 2008)",
            "manufacturer": manu,
            "pixel_pitch_um": pitch,
            "width_px": w,
            "height_px": h,
            "adc_bits": ADC_BITS,
            "black_level_dn": BLACK_DN,
            "channel": "green",
            "analog_gain": 1.0,
            "temperature_c": 25.0,
            "optical_format": fmt,
            "sensitivity_truth_e_per_lux_s": round(sens, 1),
            "simulated": "yes",
            "note": SIMULATED_NOTE,
        }
        prov = {"table1_at_pitch": table1_at(pitch), "generation_row": GENERATION_ROW, "sources": SOURCES}
        _write(name, truth, md, SEEDS[name], out, pitch_um=pitch, calibrated=True, provenance=prov)


#: real sensors built from datasheet values: table id -> what the table does not give
DATASHEET = {
    "imx363_isetcam": dict(name="Sony_IMX363_1.40um", width_px=4032, height_px=3024, black_level_dn=64.0, seed=1401),
    "imx900_lcg": dict(name="Sony_IMX900_2.25um_LCG", width_px=2064, height_px=1552, black_level_dn=240.0, seed=2251),
    "imx455_asi6200_g0": dict(
        name="Sony_IMX455_3.76um_gain0", width_px=9576, height_px=6388, black_level_dn=64.0, seed=3761
    ),
    "imx174_pointgrey": dict(name="Sony_IMX174_5.86um", width_px=1936, height_px=1216, black_level_dn=64.0, seed=5861),
}


def _num(x):
    return float(x) if x not in (None, "") else None


def _spec_rows() -> list[dict]:
    with open(HERE / "sensor_specs" / "sensor_characterization_table.csv", newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def datasheet_sensors(out: Path = HERE / "datasheet"):
    rows = {r["id"]: r for r in _spec_rows()}
    for rid, extra in DATASHEET.items():
        r = rows[rid]
        pitch = _num(r["pixel_um"])
        bits = int(float(r["adc_bits"]))
        black = extra["black_level_dn"]
        fw = _num(r["saturation_e"])
        assumed = []
        k = _num(r["conv_gain_e_per_DN"])
        if k is None:
            k = fw / (2**bits - 1 - black)
            assumed.append("conversion gain not published: K = saturation / ADC range (the ADC matched to the well)")
        qe = _num(r["qe_pct"])
        calibrated = qe is not None
        if not calibrated:
            assumed.append(
                "QE not published for this operating point: no photons_per_pixel or exposure_lux_s "
                "columns (TR at H0 cannot be computed)"
            )
        else:
            assumed.append(
                f"QE {qe:g} % at {r['qe_nm'] or '?'} nm used as the QE at 555 nm for the lux.s conversion (Eq. 4)"
            )
        dc = _num(r["dark_current_e_per_s"]) or 0.0
        prnu = (_num(r["prnu_pct"]) or 0.0) / 100.0
        dsnu = _num(r["dsnu_e"]) or 0.0
        truth = SensorTruth(
            conversion_gain_e_per_dn=k,
            read_noise_e=_num(r["read_noise_e"]),
            full_well_e=fw,
            dark_current_e_per_s=dc,
            quantum_efficiency=(qe / 100.0) if calibrated else 0.6,
            prnu_frac=prnu,
            dsnu_e=dsnu,
            full_well_spread_frac=0.005,
            adc_bits=bits,
            black_level_dn=black,
        )
        name = extra["name"]
        md = {
            "sensor": f"{r['sensor']} built from datasheet values ({r['operating_point']})",
            "manufacturer": "Sony",
            "pixel_pitch_um": pitch,
            "width_px": extra["width_px"],
            "height_px": extra["height_px"],
            "adc_bits": bits,
            "black_level_dn": black,
            "channel": "mono",
            "built_from": f"datasheet values, sensor_specs/sensor_characterization_table.csv id {rid} "
            f"(confidence {r['confidence']}; source: {r['source']})",
            "simulated": "yes (PTC simulated from published parameters)",
            "note": "built from datasheet values: the parameters are published, the PTC is simulated",
        }
        prov = {
            "table_id": rid,
            "table_row": r,
            "assumptions": assumed,
            "resolution": "width/height from the manufacturer's public product specification (not in the table)",
            "saturation": "the table's saturation capacity is used as the clip charge (full well)",
        }
        _write(name, truth, md, extra["seed"], out, pitch_um=pitch, calibrated=calibrated, provenance=prov)


if __name__ == "__main__":
    table2_sensors()
    datasheet_sensors()
    print(
        "wrote", sorted(p.name for p in HERE.glob("*.csv")), sorted(p.name for p in (HERE / "datasheet").glob("*.csv"))
    )
