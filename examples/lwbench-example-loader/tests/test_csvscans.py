"""The example loader's own tests: lwbench's dataset conformance kit, then what is particular to
it -- a sensor model derived from scans that do not describe their sensor, and flagged when it is
a guess."""

from __future__ import annotations

import numpy as np
import pytest
from lwbench_example_loader import CsvScans, read_csv_scan, write_csv_scan

from lwbench import DataWarning, get_sensor
from lwbench.testing import check_dataset, room_scan

SENSOR = get_sensor("vlp16")


def _folder(tmp_path, *, shuffled: bool, scans: int = 2):
    """Scans of a VLP-16 in a room written as .csv: in the sensor's ring-major order (the order
    tells the beam table: exact) or shuffled, as a voxel filter or a keyframe set leaves them (a
    guess)."""
    folder = tmp_path / ("shuffled" if shuffled else "ordered")
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(scans):
        points = room_scan(SENSOR, seed=i, index=i).points
        write_csv_scan(folder / f"{i:06d}.csv", points[rng.permutation(len(points))] if shuffled else points)
    return folder


def test_the_loader_keeps_lwbenchs_dataset_contract(tmp_path):
    check_dataset(CsvScans, {"path": str(_folder(tmp_path, shuffled=False))})


def test_scans_in_ring_order_give_the_sensors_own_model_not_a_guess(tmp_path):
    ds = CsvScans(path=str(_folder(tmp_path, shuffled=False)))
    assert not ds.sensor_guessed and ds.derivation.exact
    assert ds.sensor.n_beams == SENSOR.n_beams
    assert ds.sensor.azimuth_step_deg == pytest.approx(SENSOR.azimuth_step_deg, rel=0.01)


def test_shuffled_scans_give_a_guessed_model_with_a_warning(tmp_path):
    ds = CsvScans(path=str(_folder(tmp_path, shuffled=True)))
    with pytest.warns(DataWarning, match="sensor model guessed"):
        frame = ds[0]
    assert ds.sensor_guessed and ds.source_info()["sensor guessed"] is True
    assert frame.sensor.n_beams == SENSOR.n_beams  # snapped to the VLP-16's table
    assert frame.sensor.azimuth_step_deg == pytest.approx(SENSOR.azimuth_step_deg, rel=0.01)
    assert len(ds[1]) == len(read_csv_scan(ds.files[1]))


def test_sniff_answers_for_its_folders_only(tmp_path):
    assert CsvScans.sniff(_folder(tmp_path, shuffled=False, scans=1))
    assert not CsvScans.sniff(tmp_path / "missing") and not CsvScans.sniff(tmp_path / "ordered" / "000000.csv")
