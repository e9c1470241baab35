"""The ``sim`` dataset: scans ray-cast through a procedural scene along its ground-truth path.

Determinism: the scene is a function of ``(scene, seed)``; frame ``i``'s noise and dropouts come
from a generator seeded with ``(seed, i)``, so a frame is the same whatever order frames are
read in (parallel workers, resumed runs) and whether it comes from the disk cache or not.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import replace
from pathlib import Path as FsPath

import numpy as np

from lwbench import Dataset, Frame, Param, ParameterError, SensorModel, get_sensor

from .cache import ScanCache
from .raycast import Raycaster, Scan, ego_mask
from .scenes import SCENES, Scene

# Bump whenever a change alters generated scans: it is part of the cache key and of identity(),
# so results computed on an older simulator are never mistaken for results on the new one.
SIM_VERSION = "6"  # 6: traversals (another day's parked cars), cars drawn from the day's generator

# A second drive along the same path is offset sideways (a car never repeats its lane position
# to the centimetre) and starts half a scan later, so its scans are not taken where the
# mapping drive's were.
TRAVERSAL_LATERAL = (0.0, 0.35, -0.25, 0.5)


@functools.lru_cache(maxsize=8)
def _world(scene: str, seed: int, day: int, pid: int) -> tuple[Scene, Raycaster]:
    """Build (once per process) a scene as it is on ``day`` and its ray-casting structure.

    ``pid`` is part of the key so that a forked worker builds its own Embree scene instead of
    using a parent's, whose thread pool did not survive the fork.
    """
    del pid
    rng = np.random.default_rng([seed, _SCENE_CODES[scene]])
    world = SCENES[scene](rng, day=np.random.default_rng([seed, _SCENE_CODES[scene], 1000 + day]))
    return world, Raycaster(world.mesh)


_SCENE_CODES = {"tunnel": 1, "urban": 2, "indoor": 3, "town": 4}


def _resolve_sensor(name: str, scene: Scene) -> SensorModel:
    if name == "auto":
        return get_sensor(scene.sensor)
    if name.endswith(".json"):
        p = FsPath(name)
        if not p.is_file():
            raise ParameterError(f"sim: sensor file {name} does not exist")
        return SensorModel.from_dict(json.loads(p.read_text()))
    try:
        return get_sensor(name)
    except ValueError as e:
        raise ParameterError(f"sim: {e}") from None


class SimDataset(Dataset):
    """Simulated LiDAR sequences with ground-truth poses (the default dataset).

    The vehicle starts ``start`` metres along the scene's path (by default where the scene says:
    10 m inside the tunnel's portal, at the start of the urban drive, at the indoor corridor's
    end) and moves at ``speed`` m/s; consecutive scans are one sensor period apart (VLP-16 in
    the tunnel at 1 m/s and 4 Hz: 0.25 m). ``frames=0`` drives on to the end of the path.
    """

    name = "sim"
    is_default = True
    description = "built-in LiDAR simulator: tunnel, urban, indoor or town scene with ground-truth poses"
    params = (
        Param("scene", "str", "tunnel", "procedural scene", choices=tuple(SCENES)),
        Param("sensor", "str", "auto", "auto (the scene's sensor), a preset name or a sensor.json path"),
        Param("frames", "int", 20, "number of consecutive scans; 0 = the whole path", low=0),
        Param("seed", "int", 0, "seed of the scene and of the per-frame noise", low=0),
        Param("noise", "float", 0.01, "range noise standard deviation (m)", low=0.0, high=1.0),
        Param("dropout", "float", 0.01, "probability that a ray returns nothing", low=0.0, high=0.99),
        Param("speed", "float", 0.0, "vehicle speed (m/s); 0 = the scene's default", low=0.0, high=100.0),
        Param("start", "float", None, "metres along the path to start at (default: the scene's; "
              "tunnel 0 = 6 m outside the portal)", low=0.0),
        Param("distortion", "bool", False, "motion distortion: each column cast from its own pose"),
        Param("traversals", "int", 1, "drives along the path: 2 = a mapping drive then a tracking drive on another "
              "day (other parked cars, noise and dropouts; 0.35 m further left, half a scan later); frames is per "
              "drive", low=1, high=len(TRAVERSAL_LATERAL)),
        Param("cache", "bool", True, "keep generated scans on disk (KITTI layout, LWBENCH_CACHE)"),
    )

    def __init__(self, **params) -> None:
        super().__init__(**params)
        cfg = self.config
        if cfg["scene"] not in SCENES:
            raise ParameterError(f"sim: scene {cfg['scene']!r} is not available; have {sorted(SCENES)}")
        self._worlds = [_world(cfg["scene"], cfg["seed"], day, os.getpid()) for day in range(cfg["traversals"])]
        self.world, self._caster = self._worlds[0]
        # The frames declare the range noise the simulator adds (not the preset's datasheet
        # figure, 3 cm where it adds 1 cm): the noise floor and the range pairing read it.
        self.sensor = replace(_resolve_sensor(cfg["sensor"], self.world), range_noise_m=float(cfg["noise"]))
        self._blocked = ego_mask(self._caster.sensor_rays(self.sensor)[0], self.world.ego_boxes)
        self.speed = cfg["speed"] or self.world.speed
        self.step = self.speed / self.sensor.rate_hz
        s0 = self.world.s_start if cfg["start"] is None else cfg["start"]
        room = self.world.s_end - s0
        available = int(np.floor(room / self.step + 1e-9)) + 1 if room >= 0 else 0
        if available < 1:
            raise ParameterError(
                f"sim: start={cfg['start']} is past the end of the {cfg['scene']} path "
                f"(driveable up to {self.world.s_end:.1f} m)"
            )
        n = cfg["frames"] or available
        if n > available:
            raise ParameterError(
                f"sim: {cfg['scene']} at {self.speed:g} m/s and {self.sensor.rate_hz:g} Hz has room for "
                f"{available} frames from {s0:g} m along the path, asked for {n}"
            )
        if cfg["traversals"] > 1 and n + 0.5 > available:
            raise ParameterError(
                f"sim: a second drive starts half a scan later; ask for at most {available - 1} frames"
            )
        self._per = n
        self._n = n * cfg["traversals"]
        self._s = np.concatenate([s0 + self.step * (np.arange(n) + 0.5 * t) for t in range(cfg["traversals"])])
        self._lateral = np.repeat(np.asarray(TRAVERSAL_LATERAL[: cfg["traversals"]]), n)
        self.poses = self._poses_at(self._s, self._lateral)
        self.timestamps = np.arange(self._n) / self.sensor.rate_hz
        self._cache = None
        if cfg["cache"]:
            self._cache = ScanCache.open(self._cache_key(), self.poses, self.timestamps, self.sensor)

    def _poses_at(self, s: np.ndarray, lateral: np.ndarray) -> np.ndarray:
        poses = self.world.path.poses(s, self.world.sensor_height, self.world.follow_pitch)
        poses[:, :3, 3] += lateral[:, None] * self.world.path.lateral(s)
        return poses

    # -- Dataset API ------------------------------------------------------------------------
    def __len__(self) -> int:
        return self._n

    def traversals(self) -> list[list[int]]:
        """Frame indices of each drive: with ``traversals=2``, the mapping drive then the
        tracking drive (what the localization metric builds its map from and tracks)."""
        return [list(range(t * self._per, (t + 1) * self._per)) for t in range(self.config["traversals"])]

    @property
    def has_poses(self) -> bool:
        return True

    def pose(self, index: int) -> np.ndarray:
        """The path's pose: no ray cast needed."""
        return self.poses[index]

    def frame(self, index: int) -> Frame:
        if not 0 <= index < self._n:
            raise IndexError(f"sim: frame {index} out of range (0..{self._n - 1})")
        scan = self._cache.load(index) if self._cache is not None else None
        if scan is None:
            scan = self.simulate(index)
            if self._cache is not None:
                self._cache.store(index, scan)
        return Frame(
            scan.points, self.sensor, index=index, timestamp=float(self.timestamps[index]),
            pose=self.poses[index], intensity=scan.intensity, ring=scan.ring, time=scan.time,
        )

    def simulate(self, index: int) -> Scan:
        """Ray-cast frame ``index`` (no cache): the reference the cache must reproduce."""
        cfg = self.config
        rng = np.random.default_rng([cfg["seed"], index])
        caster = self._worlds[index // self._per][1]
        column_poses = None
        if cfg["distortion"]:
            cols = np.arange(self.sensor.n_azimuth) / self.sensor.n_azimuth
            s = self._s[index] + self.step * cols
            column_poses = self._poses_at(s, np.full(len(s), self._lateral[index]))
        return caster.scan(
            self.sensor, self.poses[index], rng, noise=cfg["noise"], dropout=cfg["dropout"],
            column_poses=column_poses, blocked=self._blocked,
        )

    def identity(self) -> str:
        """What the data is: every parameter but ``cache`` (which changes where, not what),
        the simulator version and the resolved sensor model."""
        return f"{self.name}:{self._cache_key()}"

    def _cache_key(self) -> str:
        what = {k: v for k, v in self.config.items() if k != "cache"}
        what["sensor"] = self.sensor.to_dict() if self.config["sensor"] == "auto" else self.sensor.to_json()
        what["version"] = SIM_VERSION
        h = hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:16]
        return f"{self.config['scene']}-{h}"
