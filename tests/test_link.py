"""The scout -> base link (lwbench.link): real sockets on 127.0.0.1, a real token bucket, real
processes; every wait bounded, every random choice seeded. Timing is never asserted: what is
checked holds however slow the machine is (the bucket's byte bound, which frames arrive, the
base's map against the raw map)."""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from lwbench import Frame, SensorModel
from lwbench.io import write_kitti_sequence
from lwbench.link import LinkModel, StreamSettings, TokenBucket, parse_cap, reference_map, run_stream
from lwbench.link.transmit import Transmitter
from lwbench.link.wire import END, FRAME, HEADER, HELLO, WireError, pack, pack_json, read_message
from lwbench.testing import room_scan

SMALL16 = SensorModel("small16", tuple(np.linspace(-15, 15, 16)), 0.8, 0.2, 20.0, 4.0)  # 7,200 rays at 4 Hz


# ------------------------------------------------------------------------------------ units
class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += dt


def test_the_token_bucket_lets_through_at_most_its_burst_plus_its_rate():
    clock = FakeClock()
    bucket = TokenBucket(1000.0, 500, clock=clock, sleep=clock.sleep)
    rng = np.random.default_rng(0)
    sent, start = 0, clock.t
    for _ in range(200):
        n = int(rng.integers(1, 501))
        granted = bucket.take(n)
        sent += n
        assert sent <= 500 + 1000.0 * (granted - start) + 1e-6  # never more than the bucket allows
        clock.t += float(rng.choice([0.0, 0.0, 0.3]))  # idle now and then: tokens pile up, to 500 at most
    assert bucket.take(1) >= start
    assert TokenBucket(None, 1400, clock=clock, sleep=clock.sleep).take(10**9) == clock.t  # no cap
    with pytest.raises(ValueError, match="exceed the bucket"):
        bucket.take(501)


def test_caps_parse():
    assert parse_cap("50") == 50.0 and parse_cap("none") is None and parse_cap("0") is None
    with pytest.raises(ValueError, match="KB/s"):
        parse_cap("fast")
    assert LinkModel(50.0).bucket == 5000 and LinkModel(5.0).bucket == 1400  # 100 ms of rate, one packet at least


def test_framing_reads_back_and_refuses_a_broken_header():
    a, b = socket.socketpair()
    with a, b:
        a.sendall(pack_json(HELLO, 0, 0.0, {"x": 1}) + pack(FRAME, 7, 12.5, b"payload") + pack(END, 0, 0.0, b""))
        hello, frame, end = (read_message(b) for _ in range(3))
        assert hello.json() == {"x": 1} and (frame.seq, frame.due, frame.body) == (7, 12.5, b"payload")
        assert end.kind == END
        bad = bytearray(pack(FRAME, 1, 0.0, b"abc"))
        bad[10] ^= 0x40
        a.sendall(bytes(bad))
        with pytest.raises(WireError, match="bad message header"):
            read_message(b)
    a, b = socket.socketpair()
    with a, b:
        a.sendall(pack(FRAME, 2, 0.0, b"abcdef")[:28])
        a.close()
        with pytest.raises(WireError, match="closed before a message body|closed inside a message"):
            read_message(b)


class _Sink:
    """A base stand-in: accepts on 127.0.0.1, reads messages, records frame bodies."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.frames: dict[int, bytes] = {}
        self.hellos = 0
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        self.server.settimeout(20)
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            conn.settimeout(20)
            with conn:
                try:
                    while (msg := read_message(conn)) is not None:
                        if msg.kind == HELLO:
                            self.hellos += 1
                        elif msg.kind == FRAME:
                            self.frames[msg.seq] = msg.body
                        elif msg.kind == END:
                            return
                except (OSError, WireError):
                    continue

    def close(self) -> None:
        self.thread.join(20)
        self.server.close()


def _transmit(link: LinkModel, payloads: list[bytes], depth: int, gap: float = 0.0):
    sink, events = _Sink(), []
    lock = threading.Lock()

    def log(e: dict) -> None:
        with lock:
            events.append(e)

    t0 = time.monotonic()
    tx = Transmitter(("127.0.0.1", sink.port), link, {"stream": {}}, depth=depth, log=log, t0=t0)
    assert tx.connect()
    tx.start()
    for i, p in enumerate(payloads):
        tx.offer(i, t0, p)
        time.sleep(gap)
    tx.close(time.monotonic() + 30.0, {})
    sink.close()
    return sink, events, tx, t0


def test_the_transmitter_keeps_the_newest_frames_and_stays_under_the_cap():
    rng = np.random.default_rng(1)
    payloads = [rng.bytes(20_000) for _ in range(10)]
    link = LinkModel(rate_kbps=200.0, burst=20_000)
    sink, events, tx, t0 = _transmit(link, payloads, depth=2)
    dropped = {e["seq"] for e in events if e["ev"] == "dropped_queue"}
    sent = {e["seq"] for e in events if e["ev"] == "sent"}
    assert sent == set(sink.frames) and not sent & dropped and sent | dropped == set(range(10))
    assert 9 in sent and len(dropped) >= 6  # offered at once: the queue kept the newest two
    assert all(sink.frames[s] == payloads[s] for s in sent)
    # The bucket's bound, whatever the machine's speed: bytes <= burst + rate * elapsed.
    assert tx.stats.bytes <= link.bucket + link.rate * (tx.stats.last - t0) + 1
    hello = len(pack_json(HELLO, 0, 0.0, {"stream": {}}))
    assert tx.stats.bytes == sum(len(payloads[s]) + HEADER for s in sent) + hello


def test_loss_and_corruption_are_seeded_and_never_pass_as_good_frames():
    rng = np.random.default_rng(2)
    sizes = [500, 28_000] * 30  # one packet or twenty
    payloads = [rng.bytes(n) for n in sizes]
    link = LinkModel(loss=0.02, corrupt=0.2, seed=7)
    runs = [_transmit(link, payloads, depth=100)[:2] for _ in range(2)]
    (sink, events), (_, events2) = runs
    fate = {e["seq"]: (e["ev"], e["corrupted"]) for e in events if e["ev"] in ("sent", "lost")}
    assert fate == {e["seq"]: (e["ev"], e["corrupted"]) for e in events2 if e["ev"] in ("sent", "lost")}  # seeded
    lost = {s for s, (ev, _) in fate.items() if ev == "lost"}
    assert lost and not lost & set(sink.frames) and len(fate) == len(payloads)
    big = sum(len(payloads[s]) > 500 for s in lost)
    assert big > 2 * (len(lost) - big)  # twenty packets, twenty chances to lose the frame
    for s, body in sink.frames.items():
        diff = np.unpackbits(np.frombuffer(body, np.uint8) ^ np.frombuffer(payloads[s], np.uint8)).sum()
        assert diff == (1 if fate[s][1] else 0)  # a corrupted frame differs in exactly one bit


# ------------------------------------------------------------------------- whole streams
@pytest.fixture(scope="module")
def moving_room(tmp_path_factory) -> Path:
    frames = []
    for i in range(40):
        f = room_scan(SMALL16, seed=9, index=i, dropout=0.02)
        pose = np.eye(4)
        pose[:3, 3] = (0.05 * i, 0.02 * i, 0.0)
        frames.append(Frame(f.points, SMALL16, index=i, timestamp=i / 4, pose=pose, intensity=f.intensity))
    return write_kitti_sequence(frames, tmp_path_factory.mktemp("room") / "seq")


def _frames(folder: Path, n: int) -> list[Frame]:
    from lwbench_plugins.files import KittiDataset

    ds = KittiDataset(path=str(folder))
    return [ds[i] for i in range(n)]


@pytest.mark.heavy
def test_an_uncapped_raw_stream_delivers_every_frame_and_the_raw_map(moving_room, tmp_path):
    frames = _frames(moving_room, 8)
    run = run_stream({"name": "kitti", "params": {"path": str(moving_room)}}, {"name": "raw", "params": {}},
                     LinkModel(), StreamSettings(frames=8, drain_s=1.0), rate_hz=4.0,
                     reference=reference_map(frames, 0.2), workdir=tmp_path)
    s = run.summary()
    assert s["on_time"] + s["late"] == 8 and s["dropped"] == s["lost"] == s["rejected"] == 0
    assert run.iou == 1.0 and run.map_voxels == run.reference_voxels > 0
    hello = json.loads((tmp_path / "config.json").read_text())
    assert hello["frames"] == 8
    # Every byte on the wire accounted for: the HELLO, then a header and the payload per frame.
    payloads = [o.payload_bytes for o in run.outcomes]
    assert run.wire_bytes > sum(payloads) + 8 * HEADER
    assert run.wire_bytes - sum(payloads) - 8 * HEADER < 2000
    assert all(set(o.parts) == {"encode", "queue", "transfer", "decode"} for o in run.outcomes)


@pytest.mark.heavy
def test_a_restarted_base_resumes_and_corrupted_payloads_never_reach_the_map(moving_room, tmp_path):
    from lwbench import OccupancyMap

    n = 40  # 10 s: a restarted base takes seconds to come up on a loaded machine (imports, warm-up)
    settings = StreamSettings(frames=n, drain_s=1.0, restart_at=0.9, restart_down_s=0.3)
    link = LinkModel(corrupt=0.25, seed=3)
    run = run_stream({"name": "kitti", "params": {"path": str(moving_room)}}, {"name": "rangeimage", "params": {}},
                     link, settings, rate_hz=4.0, reference=reference_map(_frames(moving_room, n), 0.2),
                     workdir=tmp_path)
    s = run.summary()
    assert run.base_starts == 2
    base = [json.loads(line) for line in (tmp_path / "base.jsonl").read_text().splitlines()]
    starts = [e for e in base if e["ev"] == "start"]
    assert len(starts) == 2 and starts[1]["resumed"] == sum(
        1 for e in base[: base.index(starts[1])] if e["ev"] == "frame" and e["status"] == "ok")
    ok = [e for e in base if e["ev"] == "frame" and e["status"] == "ok"]
    rejected = [e for e in base if e["ev"] == "frame" and e["status"] == "rejected"]
    assert s["rejected"] == len(rejected) and all("checksum" in e["error"] for e in rejected)
    scout = [json.loads(line) for line in (tmp_path / "scout.jsonl").read_text().splitlines()]
    corrupted = {e["seq"] for e in scout if e["ev"] == "sent" and e["corrupted"]}
    assert {e["seq"] for e in rejected} <= corrupted and not corrupted & {e["seq"] for e in ok}
    restart = starts[1]["t"]
    assert any(e["recv_end"] > restart for e in ok)  # frames after the restart arrived and were decoded
    assert s["dropped"] >= 1 and sum(s["dropped_why"].values()) == s["dropped"]
    # The final map is exactly the map of the frames the base accepted, across both of its lives.
    sensor = _frames(moving_room, 1)[0].sensor
    expected = OccupancyMap(sensor, 0.2)
    for e in ok:
        expected.insert(np.load(tmp_path / "frames" / f"{e['seq']:06d}.npy"), np.asarray(e["pose"]))
    assert np.array_equal(np.load(tmp_path / "map.npy"), expected.occupied())
    assert s["on_time"] + s["late"] == len(ok) and s["on_time"] + s["late"] + s["dropped"] + s["rejected"] == n


@pytest.mark.heavy
def test_stream_command_prints_the_table_and_writes_fig6d(moving_room, tmp_path):
    from typer.testing import CliRunner

    from lwbench.cli import app

    res = CliRunner().invoke(app, ["stream", "--dataset", str(moving_room), "--codec", "raw", "--cap", "20",
                                   "--frames", "4", "--drain", "0.5", "--out", str(tmp_path)],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert "on time" in res.stdout and "raw" in res.stdout
    assert (tmp_path / "fig6d_20KBps.png").stat().st_size > 10_000 and (tmp_path / "fig6d_20KBps.svg").is_file()
    data = json.loads((tmp_path / "stream.json").read_text())
    (r,) = data["runs"]
    # 20 KB/s cannot carry a 86 kB raw scan in a period: none on time; the bucket's bound holds.
    assert r["on_time"] == 0 and r["kbps"] <= 20.0 * 1.05 + r["link_model"]["mtu"] / 1000
    res = CliRunner().invoke(app, ["stream", "--dataset", str(moving_room), "--cap", "fast"])
    assert res.exit_code == 2 and "--cap" in res.output


@pytest.mark.heavy
def test_stream_takes_its_dataset_and_codecs_from_a_run_file(moving_room, tmp_path):
    """The Fig. 6d setting is a run file, not names in core: --config gives the dataset, the codecs
    (the first is the byte ratios' reference) and their settings; contradictions are refused."""
    from typer.testing import CliRunner

    from lwbench.cli import app

    run_file = tmp_path / "two.toml"
    run_file.write_text(f'frames = 3\n[[dataset]]\nname = "{moving_room}"\n[[codec]]\nname = "raw"\n'
                        '[[codec]]\nname = "random"\nparams = { ratio = 0.05 }\n')
    res = CliRunner().invoke(app, ["stream", "--config", str(run_file), "--cap", "none", "--drain", "0.5",
                                   "--out", str(tmp_path / "s")], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    runs = json.loads((tmp_path / "s" / "stream.json").read_text())["runs"]
    assert [(r["codec"], r["frames"]) for r in runs] == [("raw", 3), ("random", 3)]
    assert "raw/random bytes on the wire -- " in " ".join(res.stdout.split())
    res = CliRunner().invoke(app, ["stream", "--config", str(run_file), "--codec", "raw"])
    assert res.exit_code == 2 and "--config" in res.output
    (tmp_path / "seeds.toml").write_text(run_file.read_text().replace("frames = 3", "frames = 3\nseeds = [0, 1]"))
    res = CliRunner().invoke(app, ["stream", "--config", str(tmp_path / "seeds.toml")])
    assert res.exit_code == 2 and "one dataset with one seed" in " ".join(res.output.split())


def test_the_fig6d_run_file_streams_raw_gmm_vsgp_on_the_tunnel():
    from lwbench.registry import get_registry
    from lwbench.run.config import read_run_file

    request = read_run_file(Path(__file__).parents[1] / "examples" / "runs" / "fig6d.toml")
    (plan,) = request.plans(get_registry())
    assert [c.name for c in plan.configs] == ["raw", "gmm", "vsgp"] and plan.dataset.params["scene"] == "tunnel"
    assert {"fit_points": 4000, "max_iter": 20}.items() <= plan.configs[1].params.items()


@pytest.mark.slow
def test_at_50_kbps_vsgp_gets_through_and_raw_does_not_on_the_sim_tunnel(tmp_path):
    """The issue's headline, checked with margins that hold on a loaded machine: compute may make
    frames late (the breakdown says so); the link itself carries vsgp within a period, not raw."""
    from lwbench.link import run_study
    from lwbench.registry import get_registry
    from lwbench.run.plan import DatasetSpec
    from lwbench.transcode import codec_config

    reg = get_registry()
    spec = DatasetSpec("sim", {"scene": "tunnel", "frames": 24, "seed": 0})
    configs = [codec_config(reg, c, []) for c in ("raw", "vsgp")]
    result = run_study(reg, spec, configs, [LinkModel(50.0)], StreamSettings(frames=24, encode="ahead"))
    raw, vsgp = result.runs
    assert raw.count("on_time") == 0 and raw.count("on_time", "late") <= 1
    sv = vsgp.summary()
    assert sv["dropped_why"].get("queue full", 0) == 0 and sv["lost"] == 0
    transfer = [o.parts["transfer"] + o.parts["queue"] for o in vsgp.outcomes if o.parts]
    assert len(transfer) >= 6 and np.median(transfer) < 0.25  # the link's share of a period
    assert raw.wire_bytes / vsgp.wire_bytes > 3 and vsgp.iou > raw.iou
