"""``lwbench view``: an original scan beside its decoded cloud, coloured by error.

Each decoded point is coloured by its distance to the nearest original point (what the codec
made up or moved) and each original point by its distance to the nearest decoded point (what the
codec lost), on one colour scale. Where a display exists the pair opens in Open3D's viewer, side
by side; where none does (a server, CI) -- or with ``--png`` -- a PNG is written instead: two
top-down panels with a shared colour bar.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lwbench.errors import DataFormatError, LwbenchError
from lwbench.frame import Frame
from lwbench.registry import Registry
from lwbench.run.plan import CodecConfig

__all__ = ["ViewPair", "has_display", "pair_from_codec", "pair_from_file", "render_png", "show_window"]


@dataclass
class ViewPair:
    original: np.ndarray
    decoded: np.ndarray
    title: str

    def errors(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-point nearest-neighbour distance (m): original -> decoded, decoded -> original."""
        from scipy.spatial import cKDTree

        def nn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            if len(a) == 0:
                return np.zeros(0)
            if len(b) == 0:
                return np.full(len(a), np.inf)
            return cKDTree(b).query(a, workers=-1)[0]

        return nn(self.original, self.decoded), nn(self.decoded, self.original)

    def scale(self, max_error: float | None) -> float:
        """The colour scale's top: given, else the 95th percentile of the finite errors."""
        if max_error is not None:
            return max_error
        e = np.concatenate(self.errors())
        e = e[np.isfinite(e)]
        return float(np.percentile(e, 95)) if len(e) and np.percentile(e, 95) > 0 else 0.01


def has_display() -> bool:
    """Whether a window can open here (an X11 or Wayland display)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _summary(frame: Frame, decoded: np.ndarray, payload_bytes: int | None, what: str) -> str:
    size = f", {payload_bytes:,} B ({frame.raw_bytes / payload_bytes:.1f}x)" if payload_bytes else ""
    return f"{what}: frame {frame.index}, {len(frame):,} -> {len(decoded):,} points{size}"


def pair_from_codec(registry: Registry, frame: Frame, config: CodecConfig) -> ViewPair:
    """Encode and decode ``frame`` exactly as a run does (a fresh decoder, bytes only)."""
    from lwbench.params import config_label
    from lwbench.run.evaluate import encode_decode

    codec_cls = registry.codec(config.name)
    enc = encode_decode(codec_cls, config, codec_cls(**config.params), frame)
    defaults = {p.name: p.default for p in codec_cls.all_params()}
    label = config_label(config.name, {k: v for k, v in config.params.items() if defaults.get(k) != v})
    return ViewPair(frame.points, enc.decoded, _summary(frame, enc.decoded, len(enc.payload), label))


def pair_from_file(registry: Registry, frame: Frame, path: Path, index: int = 0) -> ViewPair:
    """``frame`` beside a decoded cloud file (PCD/PLY/...), or what a payload file decodes to."""
    from lwbench.io import read_point_file, scan_suffix
    from lwbench.streamfile import open_payloads
    from lwbench.transcode import decoded_frames

    if path.is_file() and scan_suffix(path) is not None:
        return ViewPair(frame.points, read_point_file(path).points, f"{path.name} beside frame {frame.index}")
    source = open_payloads(path)
    if not 0 <= index < len(source.entries):
        raise DataFormatError(f"{path} holds {len(source.entries)} frame(s); --frame {index} is not one")
    one = type(source)(source.path, source.kind, source.header, [source.entries[index]], source.sensor_file)
    codec, (decoded,) = decoded_frames(registry, one)
    return ViewPair(frame.points, decoded.points, _summary(frame, decoded.points, decoded.payload_bytes,
                                                          f"{codec} from {path.name}"))


def _colours(errors: np.ndarray, vmax: float) -> np.ndarray:
    from matplotlib import colormaps

    e = np.where(np.isfinite(errors), errors, vmax)
    return colormaps["turbo"](np.clip(e / vmax, 0.0, 1.0))[:, :3]


def render_png(pair: ViewPair, path: str | Path, max_error: float | None = None) -> Path:
    """Two top-down panels (original, decoded: stacked for a long scene, side by side otherwise),
    coloured by error on one scale, with a colour bar."""
    from lwbench.plotting import pyplot

    plt = pyplot()
    e_orig, e_dec = pair.errors()
    vmax = pair.scale(max_error)
    pts = pair.original if len(pair.original) else pair.decoded
    if len(pts):
        lo, hi = np.percentile(pts[:, :2], 0.5, axis=0), np.percentile(pts[:, :2], 99.5, axis=0)
        pad = 0.05 * float(np.max(hi - lo))
        lo, hi = lo - pad, hi + pad
    else:
        lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    wide = (hi[0] - lo[0]) >= (hi[1] - lo[1])
    fig, axes = plt.subplots(2 if wide else 1, 1 if wide else 2, figsize=(10, 7) if wide else (11, 6),
                             sharex=True, sharey=True)
    sc = None
    for ax, name, cloud, err, what in (
        (axes[0], "original", pair.original, e_orig, "distance to the nearest decoded point"),
        (axes[1], "decoded", pair.decoded, e_dec, "distance to the nearest original point"),
    ):
        if len(cloud):
            order = np.argsort(err)  # large errors drawn last, on top
            sc = ax.scatter(cloud[order, 0], cloud[order, 1], c=np.minimum(err[order], vmax), s=0.4, cmap="turbo",
                            vmin=0.0, vmax=vmax, linewidths=0, rasterized=True)
        finite = err[np.isfinite(err)]
        stats = f"median {np.median(finite):.3f} m" if len(finite) else "no points"
        ax.set_title(f"{name}: {len(cloud):,} points; {what}, {stats}", fontsize=8)
        ax.set_aspect("equal")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_ylabel("y (m)")
    axes[-1].set_xlabel("x (m)")
    if sc is not None:
        fig.colorbar(sc, ax=list(axes), shrink=0.8, label=f"error (m), clipped at {vmax:.3g}")
    fig.suptitle(pair.title, fontsize=10)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130, bbox_inches="tight")
    plt.close(fig)
    return path


def show_window(pair: ViewPair, max_error: float | None = None, *, capture: Path | None = None) -> None:
    """Open3D's viewer with the original (left) and decoded (right) cloud, coloured by error.
    ``capture`` renders one frame into that image and closes (what a test with a display does)."""
    from lwbench.deps import import_open3d

    o3d = import_open3d()
    e_orig, e_dec = pair.errors()
    vmax = pair.scale(max_error)
    span = float(np.ptp(pair.original[:, 0])) if len(pair.original) else 1.0
    geometries = []
    for cloud, err, dx in ((pair.original, e_orig, 0.0), (pair.decoded, e_dec, span * 1.1)):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(cloud, np.float64) + [dx, 0.0, 0.0]))
        pc.colors = o3d.utility.Vector3dVector(_colours(err, vmax))
        geometries.append(pc)
    try:
        if capture is None:
            o3d.visualization.draw_geometries(geometries, window_name=f"lwbench view: {pair.title}")
            return
        vis = o3d.visualization.Visualizer()
        if not vis.create_window(window_name="lwbench view", visible=False):
            raise LwbenchError("Open3D could not open a window on this display")
        for g in geometries:
            vis.add_geometry(g)
        vis.poll_events()
        vis.update_renderer()
        vis.capture_screen_image(str(capture), do_render=True)
        vis.destroy_window()
    except (RuntimeError, AttributeError) as exc:
        raise LwbenchError(f"Open3D's viewer is not available here ({exc}); use --png PATH") from None
