"""Hostile scans and malformed files (docs/hostile.md has the tables).

Scans: every registered codec on empty, 1- and 3-point scans, identical points, points at the
origin and beyond the sensor's range gives either a finite decoded cloud with every metric
finite or None, or a failure row whose error says why -- never a crash, a hang, or NaN.
Files: each malformed input is one line on stderr, exit status 2, and no store written.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from lwbench import Frame, InvalidFrameError, SensorModel, get_sensor
from lwbench.cli import app
from lwbench.registry import get_registry
from lwbench.run.evaluate import Evaluator
from lwbench.run.plan import expand_codec_configs
from lwbench.testing import room_scan

REGISTRY = get_registry()
# A codec that needs more than a scan (the oracle: labels) is refused when it is planned.
CODECS = sorted(n for n, c in REGISTRY.codecs.items() if not n.startswith("test-") and not c.needs)
FAST = {name: {k: [v] for k, v in cls.test_params().items()} for name, cls in REGISTRY.codecs.items()}


def _hostile_frames() -> dict[str, Frame]:
    s = get_sensor("vlp16")
    room = room_scan(s, seed=2)
    far = room.points * (2.5 * s.max_range / np.linalg.norm(room.points, axis=1, keepdims=True))
    return {
        "empty": Frame(np.zeros((0, 3), np.float32), s),
        "one": Frame(room.points[:1], s),
        "three": Frame(room.points[:3], s),
        "identical": Frame(np.repeat(room.points[:1], 1000, axis=0), s),
        "origin": Frame(np.zeros((1000, 3), np.float32), s),
        "beyond-range": Frame(far[::8].astype(np.float32), s),
        "float64": Frame(room.points[::8].astype(np.float64), s),
    }


FRAMES = _hostile_frames()


@pytest.mark.heavy
@pytest.mark.parametrize("codec", CODECS)
def test_hostile_scans_give_a_clear_error_or_a_finite_row(codec):
    ev = Evaluator(REGISTRY)
    (config,) = expand_codec_configs(REGISTRY.codec(codec), FAST.get(codec, {}), 0)
    for label, frame in FRAMES.items():
        (result,) = ev.evaluate(frame, [config])
        if result.status == "failed":
            assert result.error and "Traceback" not in result.error, (label, result.error)
            assert not result.error.startswith(("WorkerError", "DecodeError")), (label, result.error)
            continue
        bad = {k: v for k, v in result.metrics.items() if v is not None and isinstance(v, float) and math.isnan(v)}
        assert not bad, (label, bad)


def test_nan_rows_and_wrong_shapes_never_reach_a_codec():
    s = get_sensor("vlp16")
    pts = np.ones((10, 3), np.float32)
    pts[3] = [np.inf, 0, 0]
    for bad in (pts, np.ones((10, 2), np.float32), np.ones((10, 3), np.int32)):
        with pytest.raises(InvalidFrameError):
            Frame(bad, s)


@pytest.mark.parametrize("sensor, why", [
    ({"elevations_deg": []}, "1 to 256"),
    ({"elevations_deg": [float("nan"), 1.0]}, "finite"),
    ({"azimuth_step_deg": 1e-7}, "azimuth step"),
    ({"max_range": float("inf")}, "max_range"),
    ({"elevations_deg": list(np.linspace(-40, 40, 256)), "azimuth_step_deg": 0.01}, "cells"),
])
def test_implausible_sensor_models_are_refused(sensor, why):
    d = {"name": "s", "elevations_deg": [-1.0, 1.0], "azimuth_step_deg": 0.5, "min_range": 0.1, "max_range": 50.0,
         "rate_hz": 10.0, **sensor}
    with pytest.raises(ValueError, match=why):
        SensorModel.from_dict(d)
    with pytest.raises(TypeError):
        SensorModel.from_dict({"preset": 5})


def _kitti(tmp_path, name, *, poses=None, sensor=None, times=None, meta=None):
    d = tmp_path / name
    (d / "velodyne").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(2):  # x, y, z and a non-negative intensity: one plausible record size (issue 25)
        xyzi = rng.uniform(-5, 5, (3000, 4))
        xyzi[:, 3] = rng.uniform(0, 1, 3000)
        xyzi.astype("<f4").tofile(d / "velodyne" / f"{i:06d}.bin")
    for fname, text in (("poses.txt", poses), ("sensor.json", sensor), ("times.txt", times),
                        ("sensor_metadata.json", meta)):
        if text is not None:
            (d / fname).write_text(text)
    return d


EYE = "1 0 0 0 0 1 0 0 0 0 1 0"
SENSOR = {"name": "s", "elevations_deg": [-1.0, 1.0], "azimuth_step_deg": 0.5, "min_range": 0.1, "max_range": 50,
          "rate_hz": 10}


def _malformed(tmp_path):
    cases = {}
    (tmp_path / "w.bin").write_bytes(b"\0" * 13)
    cases["bin of the wrong size"] = (tmp_path / "w.bin", "not a whole number")
    (tmp_path / "e.bin").write_bytes(b"")
    cases["empty file"] = (tmp_path / "e.bin", "empty file")
    head = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA {d}\n"
    (tmp_path / "lie.pcd").write_text(head.format(n=1000, d="ascii") + "1 2 3\n" * 10)
    cases["PCD declaring 1,000 points, holding 10"] = (tmp_path / "lie.pcd", "truncated")
    (tmp_path / "big.pcd").write_text(head.format(n=2**31, d="binary") + "x" * 100)
    cases["PCD declaring 2^31 points"] = (tmp_path / "big.pcd", "truncated")
    ply = "ply\nformat binary_little_endian 1.0\nelement vertex 5000\nproperty float x\nproperty float y\n" \
          "property float z\nend_header\n"
    (tmp_path / "hdr.ply").write_text(ply)
    cases["header-only binary PLY"] = (tmp_path / "hdr.ply", "truncated")
    (tmp_path / "cut.ply").write_bytes(ply.encode() + b"\0" * 30000)
    cases["truncated binary PLY"] = (tmp_path / "cut.ply", "truncated")
    cases["poses with NaN"] = (_kitti(tmp_path, "pn", poses=f"{EYE}\n{EYE.replace('0', 'nan', 1)}\n"), "NaN")
    cases["poses with 3 columns"] = (_kitti(tmp_path, "pc", poses="1 0 0\n1 0 0\n"), "12 numbers")
    cases["poses with text"] = (_kitti(tmp_path, "pt", poses=f"{EYE}\n{EYE.replace('0', 'x')}\n"), "not numbers")
    cases["sensor.json with zero beams"] = (_kitti(tmp_path, "s0", sensor=json.dumps({**SENSOR, "elevations_deg": []})),
                                            "beams")
    cases["sensor.json with NaN elevations"] = (
        _kitti(tmp_path, "sn", sensor=json.dumps({**SENSOR, "elevations_deg": [float("nan"), 1]})), "finite")
    cases["sensor.json with a 1e-7 deg step"] = (
        _kitti(tmp_path, "sf", sensor=json.dumps({**SENSOR, "azimuth_step_deg": 1e-7})), "azimuth step")
    cases["Ouster columns_per_frame 0"] = (
        _kitti(tmp_path, "o0", meta=json.dumps({"beam_altitude_angles": [-1, 0, 1],
                                                "lidar_data_format": {"columns_per_frame": 0}})), "columns_per_frame")
    cases["times.txt with text"] = (_kitti(tmp_path, "tt", times="0.0\nabc\n"), "not numbers")
    (tmp_path / "none").mkdir()
    (tmp_path / "none" / "readme.txt").write_text("x")
    cases["folder with no scans"] = (tmp_path / "none", "recognises")
    for name, line in (("tn", "1 nan 0 0 0 0 0 1"), ("tz", "1 0 0 0 0 0 0 0")):
        d = tmp_path / name
        d.mkdir()
        rng = np.random.default_rng(1)
        for i in range(2):
            pts = rng.uniform(-5, 5, (2000, 3))
            (d / f"scan_{i}.xyz").write_text("\n".join(" ".join(f"{v:.3f}" for v in p) for p in pts))
        (d / "poses.txt").write_text("0 0 0 0 0 0 0 1\n" + line + "\n")
    cases["TUM pose with NaN"] = (tmp_path / "tn", "NaN")
    cases["TUM zero quaternion"] = (tmp_path / "tz", "zero quaternion")
    return cases


def test_malformed_inputs_are_one_line_exit_2_and_nothing_written(tmp_path):
    runner = CliRunner()
    for label, (path, why) in _malformed(tmp_path).items():
        store = tmp_path / f"{label.replace(' ', '_')}.sqlite"
        res = runner.invoke(app, ["run", "--dataset", str(path), "--codec", "raw", "--store", str(store)],
                            catch_exceptions=False)
        err = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
        assert res.exit_code == 2, (label, res.output)
        assert len(err) == 1 and why in res.stderr, (label, res.stderr)
        assert "Traceback" not in res.output and not store.exists(), label


@pytest.mark.parametrize("where", ["dir", "text", "readonly"])
def test_a_store_that_cannot_be_one_is_one_line_and_exit_2(tmp_path, kitti_folder, where):
    target = {"dir": tmp_path, "text": tmp_path / "notes.txt", "readonly": "/proc/lwbench/results.sqlite"}[where]
    (tmp_path / "notes.txt").write_text("not a store")
    res = CliRunner().invoke(app, ["run", "--dataset", str(kitti_folder), "--codec", "raw", "--store", str(target)],
                             catch_exceptions=False)
    assert res.exit_code == 2 and res.stderr.startswith("error:") and "Traceback" not in res.output


def test_a_device_no_codec_can_use_is_refused_before_the_run(tmp_path, kitti_folder):
    store = tmp_path / "r.sqlite"
    res = CliRunner().invoke(app, ["run", "--dataset", str(kitti_folder), "--codec", "vsgp", "--param",
                                   "vsgp.device=cuda:7", "--store", str(store)], catch_exceptions=False)
    assert res.exit_code == 2 and "device" in res.stderr and not store.exists()
