"""Simulated photon-transfer data of the Gpixel GSPRINT4521 ROIs (:func:`gpixel_sensors`), from
the per-ROI results bundled in ``data/gpixel_gsprint4521`` (:func:`gpixel_truths`)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

__all__ = ["GPIXEL_CSV", "gpixel_sensors", "gpixel_truths"]


GPIXEL_CSV = Path(__file__).resolve().parents[2] / "data" / "gpixel_gsprint4521" / "roi_results.csv"


def gpixel_truths(path=GPIXEL_CSV):
    """Sensor truths from the Gpixel GSPRINT4521 per-ROI results (one per ROI and gain).

    Truth = the measured conversion gain S (e⁻/DN), temporal dark noise (as read noise, e⁻) and
    full well (e⁻) of each ROI; 12-bit ADC ("12NOR" mode); QE 0.6, no dark current, PRNU 0.5 %
    (not in the table: assumed). Returns a list of ((roi_index, gain_index), SensorTruth)."""
    from bayescap.simulate import SensorTruth

    out = []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            t = SensorTruth(
                conversion_gain_e_per_dn=float(row["S_e_per_DN"]),
                read_noise_e=float(row["temporal_dark_noise_e"]),
                full_well_e=float(row["full_well_e"]),
                quantum_efficiency=0.6,
                prnu_frac=0.005,
                full_well_spread_frac=0.005,
                adc_bits=12,
            )
            out.append(((int(row["roi_index"]), int(row["gain_index"])), t))
    return out


def gpixel_sensors(*, n_max=None, seed=0, shape=(32, 32), n_levels=30):
    """Simulated photon-transfer data for the Gpixel ROIs×gains: (list of PTCData, list of truths).

    Small frames (``shape``) keep the simulation of 1 024 sensors near a minute; every sensor
    gets its own seed (children of ``SeedSequence(seed)``)."""
    from bayescap.simulate import simulate_ptc

    tr = gpixel_truths()
    if n_max is not None:
        tr = tr[:n_max]
    kids = np.random.SeedSequence(seed).spawn(len(tr))
    datas = []
    for ((roi, g), t), k in zip(tr, kids):
        datas.append(
            simulate_ptc(
                t,
                n_levels=n_levels,
                shape=shape,
                seed=k,
                metadata={
                    "sensor": f"Gpixel GSPRINT4521 ROI {roi} gain {g} (simulated)",
                    "pixel_pitch_um": 4.5,
                    "width_px": 5120,
                    "height_px": 4096,
                },
            )
        )
    return datas, [t for _, t in tr]
