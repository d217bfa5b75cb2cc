"""Output paths and faults of the commands: outputs never over an input, checked before any
fitting, written as a whole set or not at all; names with ``$`` in plots; exit statuses."""


import pytest

from bayescap.cli import main


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    from bayescap.simulate import SensorTruth, simulate_ptc

    p = tmp_path_factory.mktemp("csv") / "cam_$5_vs_$10.csv"
    simulate_ptc(
        SensorTruth(conversion_gain_e_per_dn=2.0, read_noise_e=3.0, full_well_e=8000.0),
        seed=3,
        shape=(50, 50),
        n_levels=20,
        path=p,
        metadata={"pixel_pitch_um": 2.2},
    )
    return p


def test_dollar_in_file_name_does_not_reach_math_text(small_csv, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["fit", str(small_csv), "--quality", "fast", "--seed", "1", "--out", str(out)]) == 0
    assert (out / "ptc.png").stat().st_size > 0
    rep = tmp_path / "r.html"
    assert main(["report", str(small_csv), "-o", str(rep), "--seed", "1"]) == 0
    assert "cam_$5_vs_$10" in rep.read_text()
