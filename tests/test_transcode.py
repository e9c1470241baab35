"""``lwbench encode`` / ``decode`` / ``inspect`` on payload files: the bytes a run measures, on disk.

The sensor used here is not a preset, so every payload names it by id: decoding works only
where the stream's header (``stream.json`` / the ``.lwbs`` header) carries its table -- which a
fresh process proves (it never saw the scans).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lwbench import DataFormatError, Frame, PayloadError, SensorModel, codec_class
from lwbench.cli import app
from lwbench.io import read_point_file, write_kitti_sequence
from lwbench.registry import get_registry
from lwbench.results.leaderboard import build_leaderboard
from lwbench.results.store import ResultStore
from lwbench.run.record import DECODED, PAYLOAD
from lwbench.streamfile import open_payloads
from lwbench.testing import room_scan
from lwbench.transcode import decoded_frames, write_pcd, write_ply

runner = CliRunner()
LAB16 = SensorModel("lab16", tuple(np.linspace(-15, 15, 16)), 0.8, 0.2, 20.0, 10.0)  # 450 columns


def invoke(*args: str):
    res = runner.invoke(app, [str(a) for a in args], catch_exceptions=False)
    return res


@pytest.fixture(scope="module")
def lab_folder(tmp_path_factory) -> Path:
    frames = []
    for i in range(3):
        f = room_scan(LAB16, seed=3, index=i, dropout=0.02)
        pose = np.eye(4)
        pose[0, 3] = 0.1 * i  # with poses, the run keeps every decoded cloud (its sequence metrics need them)
        frames.append(Frame(f.points, f.sensor, index=i, timestamp=i / 10, pose=pose, intensity=f.intensity))
    return write_kitti_sequence(frames, tmp_path_factory.mktemp("lab") / "seq")


@pytest.fixture(scope="module")
def run_store(tmp_path_factory, lab_folder) -> Path:
    store = tmp_path_factory.mktemp("store") / "r.sqlite"
    res = invoke("run", "--dataset", lab_folder, "--codec", "rangeimage", "--codec", "random",
                 "--param", "random.ratio=0.2", "--store", store)
    assert res.exit_code == 0, res.output
    return store


def _run_clouds(store: Path, codec: str) -> dict[int, np.ndarray]:
    """What the run decoded: its stored payloads (what its sequence metrics re-decode), decoded by
    a receiver handed the run's sensor -- and, for the first frame, the cloud the run kept."""
    with ResultStore(store, readonly=True) as results:
        (entry,) = [e for e in build_leaderboard(results) if e.codec == codec]
        out = {}
        for f, k in entry.evaluations.items():
            payload = results.artifact(k, PAYLOAD).tobytes()
            decoder = codec_class(codec)(**entry.params).use_sensors([LAB16])
            out[f] = decoder.decode(payload)
        first = min(entry.evaluations)
        assert np.array_equal(results.artifact(entry.evaluations[first], DECODED), out[first])
        return out


@pytest.mark.heavy
@pytest.mark.parametrize("layout", ["frames", "stream"])
@pytest.mark.parametrize("codec,params", [("rangeimage", []), ("random", ["ratio=0.2"])])
def test_encode_file_decode_gives_the_run_cloud(tmp_path, lab_folder, run_store, layout, codec, params):
    words = [f"--param={p}" for p in params] + (["--stream"] if layout == "stream" else [])
    res = invoke("encode", lab_folder, "--codec", codec, "--out", tmp_path / "enc", *words)
    assert res.exit_code == 0, res.output
    target = tmp_path / "enc" / f"{codec}.lwbs" if layout == "stream" else tmp_path / "enc"
    res = invoke("decode", target, "--out", tmp_path / "dec")
    assert res.exit_code == 0, res.output
    expected = _run_clouds(run_store, codec)
    assert sorted(expected) == [0, 1, 2]
    for frame, cloud in expected.items():
        got = read_point_file(tmp_path / "dec" / f"{frame:06d}.{codec}.pcd").points  # named after 00000N.bin
        assert np.array_equal(got, cloud)
    # The decoded folder is itself a dataset, with the stream's sensor.
    sensor = json.loads((tmp_path / "dec" / "sensor.json").read_text())
    assert SensorModel.from_dict(sensor) == LAB16


def test_a_fresh_process_decodes_a_stream_of_a_sensor_it_never_saw(tmp_path, lab_folder):
    assert invoke("encode", lab_folder, "--codec", "rangeimage", "--out", tmp_path, "--stream").exit_code == 0
    (payload_meta,) = {json.dumps(open_payloads(tmp_path / "rangeimage.lwbs").header.sensors)}
    assert LAB16.sensor_id in payload_meta
    proc = subprocess.run(
        [sys.executable, "-m", "lwbench.cli", "decode", str(tmp_path / "rangeimage.lwbs"), "--out",
         str(tmp_path / "dec"), "--format", "ply"], capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in (tmp_path / "dec").glob("*.ply")) == [f"{i:06d}.rangeimage.ply" for i in range(3)]


@pytest.mark.heavy
def test_a_lone_payload_needs_its_sensor_beside_it(tmp_path, lab_folder):
    res = invoke("encode", lab_folder, "--codec", "rangeimage", "--out", tmp_path / "enc", "--frames", "1")
    assert res.exit_code == 0
    lone = tmp_path / "elsewhere"
    lone.mkdir()
    (lone / "x.lwb").write_bytes((tmp_path / "enc" / "000000.lwb").read_bytes())
    code = ("import sys; from lwbench.registry import get_registry; from lwbench.streamfile import open_payloads; "
            "from lwbench.transcode import decoded_frames; "
            "print(len(decoded_frames(get_registry(), open_payloads(sys.argv[1]))[1][0].points))")
    proc = subprocess.run([sys.executable, "-c", code, str(lone / "x.lwb")], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode != 0 and "not known to this receiver" in proc.stderr
    (lone / "sensor.json").write_text(json.dumps(LAB16.to_dict(full=True)))
    proc = subprocess.run([sys.executable, "-c", code, str(lone / "x.lwb")], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and int(proc.stdout) > 1000, proc.stderr


def test_inspect_reads_a_stream_file_and_a_payload_folder(tmp_path, lab_folder):
    assert invoke("encode", lab_folder, "--codec", "rangeimage", "--out", tmp_path / "s", "--stream").exit_code == 0
    assert invoke("encode", lab_folder, "--codec", "rangeimage", "--out", tmp_path / "f").exit_code == 0
    for target in (tmp_path / "s" / "rangeimage.lwbs", tmp_path / "f"):
        res = invoke("inspect", target)
        assert res.exit_code == 0, res.output
        assert "rangeimage" in res.stdout and "lab16" in res.stdout and "first frame decoded points" in res.stdout
    res = invoke("inspect", tmp_path / "f" / "000001.lwb")  # stream.json beside it names the sensor
    assert res.exit_code == 0 and "decoded points" in res.stdout


def test_a_damaged_stream_file_is_one_clear_error(tmp_path, lab_folder):
    assert invoke("encode", lab_folder, "--codec", "rangeimage", "--out", tmp_path, "--stream").exit_code == 0
    path = tmp_path / "rangeimage.lwbs"
    data = path.read_bytes()
    (tmp_path / "cut.lwbs").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataFormatError, match="no index at its end"):
        open_payloads(tmp_path / "cut.lwbs")
    flipped = bytearray(data)
    flipped[len(data) - 40] ^= 0x10  # inside the index
    (tmp_path / "index.lwbs").write_bytes(bytes(flipped))
    with pytest.raises(DataFormatError, match="index checksum"):
        open_payloads(tmp_path / "index.lwbs")
    source = open_payloads(path)
    flipped = bytearray(data)
    flipped[source.entries[1].offset + 50] ^= 0x01  # inside frame 1's payload
    (tmp_path / "payload.lwbs").write_bytes(bytes(flipped))
    with pytest.raises(PayloadError, match="frame 000001: payload checksum"):
        decoded_frames(get_registry(), open_payloads(tmp_path / "payload.lwbs"))
    res = invoke("decode", tmp_path / "payload.lwbs", "--out", tmp_path / "dec")
    assert res.exit_code == 2 and "checksum" in res.output
    res = invoke("encode", lab_folder, "--codec", "rangeimage", "--out", tmp_path / "x", "--param", "step=0.01,0.02")
    assert res.exit_code == 2 and "one value only" in res.output


@pytest.mark.parametrize("writer", [write_pcd, write_ply])
def test_cloud_writers_read_back_exactly(tmp_path, writer):
    pts = np.random.default_rng(0).normal(0, 5, (1000, 3)).astype(np.float32)
    path = writer(tmp_path / f"c.{writer.__name__[-3:]}", pts)
    assert np.array_equal(read_point_file(path).points, pts)


def test_a_mangled_stream_file_raises_only_lwbench_errors(tmp_path, lab_folder):
    """Seeded flips, cuts and splices anywhere in a stream file: each is refused with an
    lwbench error (one line, exit 2 on the command line) or decodes -- never another exception."""
    from lwbench import LwbenchError

    assert invoke("encode", lab_folder, "--codec", "random", "--out", tmp_path, "--stream").exit_code == 0
    data = (tmp_path / "random.lwbs").read_bytes()
    rng = np.random.default_rng(15)
    reg = get_registry()
    for case in range(150):
        blob = bytearray(data)
        kind = case % 3
        if kind == 0:
            for pos in rng.integers(0, len(blob), int(rng.integers(1, 4))):
                blob[pos] ^= 1 << int(rng.integers(0, 8))
        elif kind == 1:
            blob = blob[: int(rng.integers(0, len(blob)))]
        else:
            at = int(rng.integers(0, len(blob)))
            blob[at:at] = rng.bytes(int(rng.integers(1, 64)))
        path = tmp_path / f"m{case}.lwbs"
        path.write_bytes(bytes(blob))
        try:
            decoded_frames(reg, open_payloads(path))
        except LwbenchError:
            pass
        path.unlink()
