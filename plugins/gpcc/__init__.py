"""``gpcc``: MPEG G-PCC, the anchor of LiDAR compression research, through its reference software.

The codec runs MPEG's reference encoder/decoder ``tmc3`` (TMC13, BSD-3; v23.0-rc2 is what it
was written and measured against), found through the environment variable ``LWBENCH_TMC3`` or
on ``PATH``. lwbench does not ship it: :data:`RECIPE` says how to build it. Where it is missing
the codec still registers, ``lwbench list`` marks it unavailable with that recipe, and
encode/decode raise :class:`lwbench.MissingDependencyError` saying the same.

Geometry only. Every coordinate is rounded to the grid of ``scale`` metres (what G-PCC calls the
position quantization: this codec gives tmc3 the integer grid coordinates in the sensor frame
and codes them losslessly, ``positionQuantizationScale=1``, so the sensor stays at the origin the
angular mode needs); points that fall on the same grid cell are merged (G-PCC's
``mergeDuplicatedPoints``), so coverage may be below 1 at coarse scales. Each coordinate of a
decoded point is within ``scale/2`` of its source point's. Modes:

- ``octree``: the octree geometry coder (G-PCC's default; planar and direct modes on);
- ``predgeom``: predictive geometry (``geomTreeType=1``), cartesian prediction;
- ``angular``: predictive geometry with the angular mode (``angularEnabled=1``): each point is
  coded as (laser, azimuth, radius) predicted along its laser, from the frame's sensor model:
  ``numLasers`` = its beams, ``lasersTheta`` = tan(elevation) per beam, ``lasersZ`` = 0 (lwbench's
  sensor model has no per-beam vertical offsets), ``lasersNumPhiPerTurn`` = samples per turn
  (360 / azimuth step), ``positionAzimuthScaleLog2=12`` (a turn is 2^24 azimuth units, as the
  CTC's lossless predictive-geometry condition sets it) and ``positionAzimuthSpeed`` = 2^24 /
  samples per turn. The points are coded in the scan's own order (a spinning LiDAR's acquisition
  order; the CTC's ``sortInputByAzimuth`` re-sorts inputs that lost it, and costs 15 % more
  bytes on the simulated HDL-64E street at 1 cm). The bitstream carries the whole table: the
  decoder needs no sensor.
- ``angular-lossy``: the MPEG CTC's lossy-geometry condition for spinning LiDARs (predictive
  geometry with the angular mode, ``positionQuantisationEnabled=1``, no secondary cartesian
  residual): each point is sent as (laser, azimuth, radius) with the radius quantized to
  ``scale * 2**k`` and the azimuth to a turn / ``2**(a + 12)``, ``(k, a)`` the CTC's rate point
  ``ctc_rate`` r01..r06 (:data:`CTC_ANGULAR_LOSSY`), on an input grid of ``scale`` (the CTC's
  sources are on 1 mm: ``scale=0.001``). Every return is kept (no cells merge at 1 mm); the
  error is along the beam and across it, not on a cartesian grid.

:data:`CTC_SCALES` are the MPEG common test conditions' geometry rate points for the LiDAR
(cat3-frame) sequences, r01 (coarsest) to r06, in metres per step: the octree CTC's
``positionQuantizationScale`` for a source of 1 mm units and geometry precision 18 (the Ford
sequences): 1/512, 1/256, 1/64, 1/32, 1/8, 1/4 of a millimetre grid.

Payload: lwbench's header (codec, version, checksum) with metadata ``mode``, ``scale`` and ``n``
(the count tmc3 reconstructs), then the tmc3 bitstream as the body. Decoding is bit-exact to
tmc3's own reconstruction: tmc3 ``--mode=1`` writes the decoded grid coordinates, this codec
multiplies them by ``scale`` (in float64, then float32 as every decoder returns).

Hostile payloads: the header and counts are checked first; tmc3 then runs in a child process
with a wall-clock timeout, an address-space limit, a CPU-time limit and an output-file size limit
(as many bytes as ``n`` points need), so a crash, hang or runaway output of tmc3 on a crafted
bitstream is one :class:`lwbench.PayloadError`, never a hang; its output must be the PLY file it
writes, with exactly ``n`` points.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

import lwbench
from lwbench import (
    Frame,
    MissingDependencyError,
    Param,
    PayloadError,
    RepresentationCodec,
    check_count,
    checked_cloud,
    hookimpl,
)

__all__ = [
    "GpccCodec",
    "CTC_SCALES",
    "MODES",
    "RECIPE",
    "TMC3_ENV",
    "find_tmc3",
    "unavailable_reason",
    "read_ply",
    "encode_points",
]

TMC3_ENV = "LWBENCH_TMC3"
RECIPE = (
    "build MPEG's tmc3 (github.com/MPEGGroup/mpeg-pcc-tmc13: cmake -S . -B build -DCMAKE_BUILD_TYPE=Release && "
    "cmake --build build --target tmc3; or python3 .ci/build_tmc3.py SOURCE in an lwbench checkout) and set "
    f"{TMC3_ENV}=/path/to/tmc3 or put tmc3 on PATH"
)
MODES = ("octree", "predgeom", "angular", "angular-lossy")
#: The MPEG CTC's lossy-geometry predictive condition for spinning LiDARs (TMC13's
#: cfg/cfg-predgeom.yaml), rate r01..r06 (``ctc_rate`` 1..6) -> (positionRadiusInvScaleLog2,
#: positionAzimuthScaleLog2): the radius step is ``scale * 2**k``, the azimuth step a turn / 2**(a+12).
CTC_ANGULAR_LOSSY = {1: (8, 7), 2: (7, 7), 3: (5, 8), 4: (4, 9), 5: (2, 11), 6: (1, 12)}
#: The MPEG CTC LiDAR geometry rate points r01..r06 (metres per step), coarsest first: the octree
#: CTC's positionQuantizationScale (1/512 .. 1/4) on the Ford sequences' 1 mm grid.
CTC_SCALES = (0.512, 0.256, 0.064, 0.032, 0.008, 0.004)

#: Largest grid coordinate this codec hands tmc3 (its positions are int32; 2^24 keeps the octree
#: depth sane): with MAX_COORDINATE = 10 km the finest usable scale is about 0.6 mm.
MAX_GRID = 1 << 24
#: Child-process limits for tmc3, scaled by the point count (tmc3 decodes a 120k-point scan in
#: about 0.05 s and 60 MB): wall clock and CPU ``2 s + 5 us/point`` up to :data:`TIMEOUT_S`,
#: address space ``512 MB + 1 kB/point`` up to :data:`MEMORY_BYTES`. A crafted bitstream that
#: makes tmc3 loop costs about 2 s, not a hang.
TIMEOUT_S = 120.0
MEMORY_BYTES = 8 << 30


def _budget(n: int) -> tuple[float, int]:
    return min(TIMEOUT_S, 2.0 + 5e-6 * n), min(MEMORY_BYTES, (512 << 20) + 1024 * n)
_PLY_BYTES_PER_POINT = 24  # tmc3 writes float64 x, y, z
_PLY_HEADER_MAX = 4096


def find_tmc3() -> str | None:
    """The tmc3 binary: ``$LWBENCH_TMC3`` when set (and executable), else ``tmc3`` on PATH."""
    env = os.environ.get(TMC3_ENV, "").strip()
    if env:
        return env if os.path.isfile(env) and os.access(env, os.X_OK) else None
    return shutil.which("tmc3")


def unavailable_reason() -> str:
    """Why the codec cannot run here, in one line (``""``: tmc3 was found)."""
    if find_tmc3():
        return ""
    env = os.environ.get(TMC3_ENV, "").strip()
    where = f"{TMC3_ENV}={env} is not an executable file" if env else f"no tmc3 on PATH and {TMC3_ENV} unset"
    return f"the tmc3 binary (MPEG G-PCC reference software): {where}; {RECIPE}"


def _tmc3() -> str:
    path = find_tmc3()
    if not path:
        raise MissingDependencyError(f"gpcc needs {unavailable_reason()}")
    return path


def _limits(file_bytes: int, seconds: float, memory: int):
    def apply() -> None:  # runs in the child, before exec
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
        cpu = int(math.ceil(seconds))
        resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu))
        resource.setrlimit(resource.RLIMIT_FSIZE, (file_bytes, file_bytes))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))

    return apply


def _run(args: list[str], cwd: str, file_bytes: int, n: int) -> tuple[int | None, str]:
    """Run tmc3 with ``args`` in ``cwd`` under the limits for ``n`` points: (exit status or None
    on timeout, output tail)."""
    seconds, memory = _budget(n)
    try:
        proc = subprocess.run(
            [_tmc3(), *args],
            cwd=cwd,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            timeout=seconds,
            preexec_fn=_limits(file_bytes, seconds, memory),
            check=False,
        )
    except subprocess.TimeoutExpired:
        return None, f"timed out after {seconds:g} s"
    text = proc.stdout.decode("utf-8", "replace").strip().splitlines()
    return proc.returncode, " | ".join(text[-3:])


def _ply_bytes(n: int) -> int:
    return _PLY_HEADER_MAX + _PLY_BYTES_PER_POINT * n


_PLY_TYPES = {
    "float64": "<f8", "double": "<f8", "float32": "<f4", "float": "<f4",
    "int32": "<i4", "int": "<i4", "uint32": "<u4", "uint": "<u4",
    "int16": "<i2", "short": "<i2", "uint16": "<u2", "ushort": "<u2",
    "int8": "i1", "char": "i1", "uint8": "u1", "uchar": "u1",
}


def read_ply(data: bytes, codec: str = "gpcc") -> np.ndarray:
    """The ``(n, 3)`` float64 x, y, z of a binary little-endian PLY as tmc3 writes it (one vertex
    element, scalar properties), or :class:`PayloadError`."""
    end = data.find(b"end_header\n", 0, _PLY_HEADER_MAX)
    if not data.startswith(b"ply\n") or end < 0:
        raise PayloadError(f"{codec} payload: tmc3 wrote no readable PLY header")
    lines = data[:end].decode("ascii", "replace").splitlines()[1:]
    n, props, element = None, [], None
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and words[1:2] != ["binary_little_endian"]:
            raise PayloadError(f"{codec} payload: tmc3 wrote a {' '.join(words[1:2])} PLY, not binary little endian")
        elif words[0] == "element":
            element = words[1] if len(words) > 1 else None
            if element == "vertex" and len(words) == 3 and words[2].isdigit():
                n = int(words[2])
            elif element == "vertex" or (len(words) == 3 and words[2] != "0"):
                raise PayloadError(f"{codec} payload: tmc3's PLY holds an unexpected element {line[:60]!r}")
        elif words[0] == "property" and element == "vertex":
            if len(words) != 3 or words[1] not in _PLY_TYPES:
                raise PayloadError(f"{codec} payload: tmc3's PLY has an unexpected property {line[:60]!r}")
            props.append((words[2], _PLY_TYPES[words[1]]))
    names = [p[0] for p in props]
    if n is None or not {"x", "y", "z"} <= set(names) or len(set(names)) != len(names):
        raise PayloadError(f"{codec} payload: tmc3's PLY has no vertex element with x, y, z")
    dtype = np.dtype(props)
    body = memoryview(data)[end + len(b"end_header\n") :]
    if len(body) != n * dtype.itemsize:
        raise PayloadError(f"{codec} payload: tmc3's PLY holds {len(body)} bytes for {n} points")
    rec = np.frombuffer(body, dtype=dtype, count=n)
    return np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)


def _write_ply(path: Path, grid: np.ndarray) -> None:
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(grid)}\nproperty float64 x\nproperty float64 y\nproperty float64 z\nend_header\n"
    )
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.ascontiguousarray(grid, dtype="<f8").tobytes())  # tmc3 reads 4-byte positions as float32


def _mode_args(mode: str, sensor: Any, ctc_rate: int = 6) -> list[str]:
    if mode == "octree":
        return ["--geomTreeType=0"]
    if mode == "predgeom":
        return ["--geomTreeType=1", "--predGeomSort=0"]
    # angular: predictive geometry + the LiDAR head model from the sensor
    if sensor is None:
        raise ValueError(f"gpcc: mode={mode} needs the frame's sensor model (laser elevations, azimuth step)")
    elev = np.radians(np.asarray(sensor.elevations_deg, dtype=np.float64))
    if not 1 <= len(elev) <= 255:
        raise ValueError(f"gpcc: the angular mode takes 1 to 255 lasers, the sensor has {len(elev)}")
    per_turn = max(1, int(round(360.0 / float(sensor.azimuth_step_deg))))
    radius_log2, scale_log2 = (0, 12) if mode == "angular" else CTC_ANGULAR_LOSSY[int(ctc_rate)]
    # a turn is 2^(scale_log2 + 12) azimuth units
    speed = max(1, min(1 << (scale_log2 + 12), int(round((1 << (scale_log2 + 12)) / per_turn))))
    n = len(elev)
    lossy = [] if mode == "angular" else [
        "--positionQuantisationEnabled=1",
        "--positionBaseQp=58",
        "--secondaryResidualDisabled=1",
    ]
    return [*lossy,
        "--geomTreeType=1",
        "--predGeomSort=0",
        "--angularEnabled=1",
        f"--numLasers={n}",
        "--lasersTheta=" + ",".join(f"{math.tan(e):.8f}" for e in elev),
        "--lasersZ=" + ",".join("0" for _ in range(n)),
        "--lasersNumPhiPerTurn=" + ",".join(str(per_turn) for _ in range(n)),
        "--lidarHeadPosition=0,0,0",
        "--predGeomAzimuthSortPrecision=1024",
        f"--positionAzimuthScaleLog2={scale_log2}",
        f"--positionAzimuthSpeed={speed}",
        f"--positionRadiusInvScaleLog2={radius_log2}",
        "--resRContextQphiThresholdPresentFlag=1",
        f"--resRContextQphiThreshold={int(1600 / speed)}",
    ]


def encode_points(
    points: np.ndarray, mode: str, scale: float, sensor: Any = None, ctc_rate: int = 6
) -> tuple[bytes, np.ndarray]:
    """tmc3's bitstream of ``points`` (metres, sensor frame) on the grid of ``scale`` m in
    ``mode`` (``angular-lossy``: at ``ctc_rate``), and the encoder's reconstruction (grid
    coordinates, float64, tmc3's order; from ``--reconstructedDataPath``)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    with np.errstate(over="ignore", invalid="ignore"):
        grid = np.round(pts / scale)
    if len(grid) and not (np.isfinite(grid).all() and np.abs(grid).max() < MAX_GRID):
        raise ValueError(f"gpcc: at scale {scale} m the scan's coordinates leave tmc3's grid (|q| < 2^24)")
    args = _mode_args(mode, sensor, ctc_rate)
    with tempfile.TemporaryDirectory(prefix="lwbench-gpcc-") as tmp:
        _write_ply(Path(tmp) / "in.ply", grid)
        rc, tail = _run(
            [
                "--mode=0",
                "--uncompressedDataPath=in.ply",
                "--compressedStreamPath=out.bin",
                "--reconstructedDataPath=rec.ply",
                "--outputBinaryPly=1",
                "--disableAttributeCoding=1",
                "--positionQuantizationScale=1",
                "--mergeDuplicatedPoints=1",
                *args,
            ],
            tmp,
            file_bytes=max(1 << 20, 4 * _ply_bytes(len(grid))),
            n=4 * len(grid),  # an encode takes longer than a decode: the budget of 4x the points
        )
        body_path, rec_path = Path(tmp) / "out.bin", Path(tmp) / "rec.ply"
        if rc != 0 or not body_path.is_file() or not rec_path.is_file():
            raise RuntimeError(f"gpcc: tmc3 failed to encode ({'exit ' + str(rc) if rc is not None else ''}): {tail}")
        body = body_path.read_bytes()
        try:
            recon = read_ply(rec_path.read_bytes())
        except PayloadError as exc:
            raise RuntimeError(f"gpcc: tmc3's reconstruction is unreadable: {exc}") from None
    return body, recon


def decode_body(body: bytes, n: int, codec: str = "gpcc") -> np.ndarray:
    """tmc3's decoded grid coordinates ``(n, 3)`` float64 of a bitstream, or ``PayloadError``."""
    with tempfile.TemporaryDirectory(prefix="lwbench-gpcc-") as tmp:
        (Path(tmp) / "in.bin").write_bytes(body)
        rc, tail = _run(
            ["--mode=1", "--compressedStreamPath=in.bin", "--reconstructedDataPath=out.ply", "--outputBinaryPly=1"],
            tmp,
            file_bytes=_ply_bytes(n),
            n=n,
        )
        out = Path(tmp) / "out.ply"
        if rc != 0:
            why = "timed out" if rc is None else (f"killed by signal {-rc}" if rc < 0 else f"exit status {rc}")
            raise PayloadError(f"{codec} payload: tmc3 could not decode the bitstream ({why}: {tail[-300:]})")
        if not out.is_file():
            raise PayloadError(f"{codec} payload: tmc3 decoded no point cloud ({tail[-300:]})")
        if out.stat().st_size > _ply_bytes(n):
            raise PayloadError(f"{codec} payload: tmc3 decoded more points than the header's {n}")
        grid = read_ply(out.read_bytes(), codec)
    if len(grid) != n:
        raise PayloadError(f"{codec} payload: tmc3 decoded {len(grid)} points, the header says {n}")
    return grid


class _Needs:
    """``GpccCodec.needs``: what the harnesses skip it for -- the tmc3 binary when it is missing."""

    def __get__(self, obj: object, owner: type | None = None) -> str:
        return unavailable_reason()


class GpccCodec(RepresentationCodec):
    """MPEG G-PCC (TMC13's tmc3): octree, predictive or angular predictive geometry at a scale."""

    name = "gpcc"
    version = "1"
    in_default_run = False  # needs an external binary, and its rows belong to the RD runs
    description = "MPEG G-PCC reference software (tmc3): octree / predictive / angular geometry on a grid"
    params = (
        Param("mode", "str", "predgeom", "geometry coder: octree, predgeom, or angular (predgeom + sensor model)",
              choices=MODES),
        Param("scale", "float", 0.01, "position quantization step in metres (CTC rate points: CTC_SCALES)",
              low=0.001, high=10.0),
        Param("ctc_rate", "int", 6, "mode=angular-lossy: the CTC's lossy predictive rate point r01..r06 (1..6)",
              low=1, high=6),
    )
    needs = _Needs()  # type: ignore[assignment]

    @classmethod
    def unavailable(cls) -> str:
        return unavailable_reason()

    @classmethod
    def missing(cls, config: dict[str, Any]) -> str:
        return unavailable_reason()

    @classmethod
    def test_params(cls) -> dict[str, Any]:
        return {"mode": "predgeom", "scale": 0.01}

    def encode(self, frame: Frame) -> bytes:
        _tmc3()
        mode, scale = str(self.config["mode"]), float(self.config["scale"])
        pts = frame.points
        meta: dict[str, Any] = {"mode": mode, "scale": scale, "n": 0}
        if not len(pts):
            return self.make_payload(frame, meta, b"")
        lwbench.check_encodable(pts, self.name, slack=math.sqrt(3.0) * scale)
        sensor = frame.sensor if mode.startswith("angular") else None
        body, recon = encode_points(pts, mode, scale, sensor, int(self.config["ctc_rate"]))
        meta["n"] = len(recon)
        return self.make_payload(frame, meta, body)

    def decode(self, data: bytes) -> np.ndarray:
        payload = self.read_payload(data)
        mode = self.meta_field(payload, "mode", str)
        scale = self.meta_field(payload, "scale", (float, int))
        n = check_count(self.meta_field(payload, "n", int), "point count", codec=self.name)
        if mode not in MODES or not 0.001 <= float(scale) <= 10.0:
            raise PayloadError(
                f"{self.name} payload: mode {mode[:20]!r} or scale {scale!r} is not one this codec writes"
            )
        if n == 0:
            if payload.body:
                raise PayloadError(f"{self.name} payload: an empty scan carries no bitstream")
            return np.zeros((0, 3), dtype=np.float32)
        if not payload.body:
            raise PayloadError(f"{self.name} payload: {n} points and no bitstream")
        _tmc3()
        grid = decode_body(payload.body, n, self.name)
        with np.errstate(over="ignore", invalid="ignore"):
            return checked_cloud(grid * float(scale), self.name)


@hookimpl
def lwbench_codecs() -> list[type[GpccCodec]]:
    return [GpccCodec]
