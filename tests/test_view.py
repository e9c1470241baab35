"""``lwbench view``: the headless PNG everywhere; Open3D's window only where a display exists."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from lwbench import get_sensor
from lwbench.cli import app
from lwbench.registry import get_registry
from lwbench.testing import room_scan
from lwbench.transcode import codec_config, write_pcd
from lwbench.view import ViewPair, has_display, pair_from_codec, pair_from_file, render_png, show_window

runner = CliRunner()


@pytest.fixture
def headless(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


def test_errors_are_nearest_neighbour_distances_both_ways():
    original = np.array([[0, 0, 0], [1, 0, 0], [5, 0, 0]], np.float32)
    decoded = np.array([[0, 0.1, 0], [1, 0, 0]], np.float32)
    e_orig, e_dec = ViewPair(original, decoded, "t").errors()
    np.testing.assert_allclose(e_orig, [0.1, 0.0, 4.0], atol=1e-6)  # the far point was lost: 4 m
    np.testing.assert_allclose(e_dec, [0.1, 0.0], atol=1e-6)
    assert ViewPair(original, decoded, "t").scale(0.5) == 0.5


def test_view_writes_a_png_where_there_is_no_display(tmp_path, headless, kitti_folder, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["view", str(kitti_folder), "--codec", "random", "--param", "ratio=0.3"])
    assert res.exit_code == 0, res.output
    assert "no display here" in res.stdout
    png = tmp_path / "lwbench-view.png"
    from matplotlib.image import imread

    img = imread(png)
    assert img.shape[0] > 300 and img.shape[1] > 300 and img[..., :3].std() > 0.05  # a picture, not a blank
    res = runner.invoke(app, ["view", str(kitti_folder)])
    assert res.exit_code == 2 and "--codec" in res.output


def test_a_decoded_file_and_the_codec_path_show_the_same_cloud(tmp_path, kitti_folder):
    reg = get_registry()
    frame = reg.dataset("kitti")(path=str(kitti_folder))[1]
    via_codec = pair_from_codec(reg, frame, codec_config(reg, "rangeimage", []))
    write_pcd(tmp_path / "d.pcd", via_codec.decoded)
    via_file = pair_from_file(reg, frame, tmp_path / "d.pcd")
    assert np.array_equal(via_file.decoded, via_codec.decoded)
    lossless = pair_from_codec(reg, frame, codec_config(reg, "raw", []))
    assert max(e.max() for e in lossless.errors()) == 0.0
    out = render_png(via_codec, tmp_path / "sub" / "v.png", max_error=0.05)
    assert out.stat().st_size > 20_000


@pytest.mark.heavy
def test_view_reads_a_frame_of_a_stream_file(tmp_path, kitti_folder, headless):
    assert runner.invoke(app, ["encode", str(kitti_folder), "--codec", "rangeimage", "--out", str(tmp_path),
                               "--stream"]).exit_code == 0
    res = runner.invoke(app, ["view", str(kitti_folder), str(tmp_path / "rangeimage.lwbs"), "--frame", "2",
                              "--png", str(tmp_path / "f2.png")])
    assert res.exit_code == 0, res.output
    assert "rangeimage from rangeimage.lwbs: frame 2" in res.stdout and (tmp_path / "f2.png").is_file()
    res = runner.invoke(app, ["view", str(kitti_folder), str(tmp_path / "rangeimage.lwbs"), "--frame", "7"])
    assert res.exit_code == 2 and "frame" in res.output


@pytest.mark.skipif(not has_display(), reason="Open3D's window needs a display (none here)")
def test_the_open3d_window_renders_the_pair(tmp_path):
    frame = room_scan(get_sensor("vlp16"), seed=1)
    pair = ViewPair(frame.points, frame.points[::3] + np.float32(0.02), "window test")
    show_window(pair, capture=tmp_path / "window.png")
    assert (tmp_path / "window.png").stat().st_size > 1000


def test_a_decoded_file_is_compared_with_the_scan_it_is_named_after(tmp_path, kitti_folder, headless):
    """Issue 33: `lwbench view FOLDER dec/000002.raw.pcd` compared it with frame 0."""
    assert runner.invoke(app, ["encode", str(kitti_folder), "--codec", "raw", "--out", str(tmp_path / "enc")]
                         ).exit_code == 0
    assert runner.invoke(app, ["decode", str(tmp_path / "enc"), "--out", str(tmp_path / "dec")]).exit_code == 0
    res = runner.invoke(app, ["view", str(kitti_folder), str(tmp_path / "dec" / "000002.raw.pcd"),
                              "--png", str(tmp_path / "v.png")])
    assert res.exit_code == 0, res.output
    assert "frame 2" in res.stdout, res.stdout
    (tmp_path / "dec" / "000002.raw.pcd").rename(tmp_path / "mine.pcd")
    res = runner.invoke(app, ["view", str(kitti_folder), str(tmp_path / "mine.pcd")])
    assert res.exit_code == 2 and "--frame N" in res.output
