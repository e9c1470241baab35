"""A fuzz campaign against vsgp's decoder (issue 23): crafted payloads (lwbench.fuzz.mutate,
CRC re-sealed), decoded out of process, counted by outcome -- and *absurd* outputs: a decoded
point farther than the payload's sensor can see (its max range) counts as a failure too.

    PYTHONPATH=tools python tools/vsgp_fuzz.py --cases 3000
    PYTHONPATH=tools python tools/vsgp_fuzz.py --cases 3000 --param residual=0.1   # the residual layer
    PYTHONPATH=tools:/tmp/old VSGP_FUZZ_BASE=vsgp_old python tools/vsgp_fuzz.py --cases 3000

``VSGP_FUZZ_BASE`` names the package whose ``VSGPCodec`` is fuzzed (default: the installed
plugin, ``lwbench_plugins.vsgp``; another one -- e.g. main's plugin copied to a package
``vsgp_old`` -- gives the "before" counts). Seeds: the conformance kit's fuzz frames with every
declared parameter choice (lwbench.fuzz.seed_payloads), at ``num_inducing=100`` as
tools/fuzz_codecs.py uses. A development script (not installed).
"""

from __future__ import annotations

import argparse
import importlib
import os
from collections import Counter

import numpy as np

from lwbench import LwbenchError

_BASE = importlib.import_module(os.environ.get("VSGP_FUZZ_BASE", "lwbench_plugins.vsgp")).VSGPCodec


class AbsurdOutput(LwbenchError):
    """A decode returned points beyond the payload's sensor's reach."""


class Checked(_BASE):  # type: ignore[misc,valid-type]
    """The codec under test, with the output bound checked after every decode."""

    def decode(self, data: bytes) -> np.ndarray:
        pts = super().decode(data)
        if len(pts):
            reach = self.read_sensor(self.read_payload(data)).max_range
            far = float(np.linalg.norm(pts.astype(np.float64), axis=1).max())
            if far > reach * 1.001 + 1e-3:
                raise AbsurdOutput(f"a decoded point {far:.3g} m away; the sensor reaches {reach:g} m")
        return pts


def worst_payloads() -> list[tuple[str, bytes]]:
    """The most expensive payloads the v2 bounds let through, by hand: many tiles, as many points
    a tile as the decoder's work budget admits (shrunk until it does), lengthscales so short
    that every column is evaluated, the general (log + exp) kernel path. Their decodes must stay
    within a second of CPU."""
    from lwbench_plugins.vsgp.decoder import DecodeConfig, plan_decode
    from lwbench_plugins.vsgp.grid import Tiling
    from lwbench_plugins.vsgp.residuals import MAX_SLOTS
    from lwbench_plugins.vsgp.wire import MAX_INDUCING, MAX_TILE_INDUCING, Body, TileModel, pack_body

    from lwbench import Payload, PayloadError, get_sensor

    rng = np.random.default_rng(0)
    out = []

    def body_of(sensor, tiling: Tiling, per_tile: int) -> Body:
        tiles = []
        for t in range(tiling.n_tiles):
            band, sector = tiling.tile(t)
            (r0, r1), (c0, c1) = tiling.band_rows(band), tiling.sector_cols(sector)
            cols = rng.uniform(c0, c1, per_tile)
            az = (np.round((cols / sensor.n_azimuth) * 65536).astype(np.int64) % 65536).astype(np.uint16)
            beam = rng.integers(r0, r1, per_tile)
            tiles.append(TileModel(az, beam, rng.uniform(-1, 1, per_tile), (2e-5, 2e-5, 0.7, 1.0, 1e-4), 5.0))
        return Body("linear", 100.0, tiling, np.full(sensor.n_beams, 128, np.uint8), tiles)

    for preset, bands, sectors in (
        ("vlp16", 1, 1),
        ("vlp16", 1, 225),
        ("hdl64e", 4, 64),
        ("hdl64e", 4, 16),
        ("os1-128", 8, 32),
        ("os1-128", 8, 4),
    ):
        sensor = get_sensor(preset)
        tiling = Tiling(sensor.n_beams, sensor.n_azimuth, bands, sectors)
        per_tile = min(MAX_TILE_INDUCING, MAX_INDUCING // tiling.n_tiles)
        while per_tile > 0:
            body = body_of(sensor, tiling, per_tile)
            try:
                plan_decode(body, sensor, DecodeConfig())
                break
            except PayloadError:
                per_tile = int(per_tile * 0.8)
        meta = {"sensor": sensor.to_wire(), "body": "q16"}
        label = f"{preset} {bands}x{sectors} tiles x {per_tile} points"
        out.append((label, Payload("vsgp", meta, pack_body("q16", body), None).to_bytes()))
        section = _fullest_residuals(sensor, rng)
        meta = {**meta, "residual": len(section)}
        label += f" + a residual layer of {MAX_SLOTS} coded returns in every cell"
        out.append((label, Payload("vsgp", meta, pack_body("q16", body) + section, None).to_bytes()))
    return out


def _fullest_residuals(sensor, rng) -> bytes:
    """The largest residual section a sensor admits: every cell holds MAX_SLOTS returns and
    every one is coded, with incompressible residuals."""
    from lwbench_plugins.vsgp.residuals import MAX_SLOTS, Slots, pack_residuals

    counts = np.full(sensor.n_rays, MAX_SLOTS, np.int64)
    cell = np.repeat(np.arange(sensor.n_rays), MAX_SLOTS)
    rank = np.tile(np.arange(MAX_SLOTS), sensor.n_rays)
    truth = rng.uniform(sensor.min_range, sensor.max_range, len(cell))
    return pack_residuals(Slots(counts, cell, rank, truth), np.full(len(cell), sensor.min_range), 1e-3, sensor)[0]


def main() -> None:
    from lwbench.fuzz import DecodeServer, class_ref, fuzz_codec

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--worst",
        action="store_true",
        help="decode the hand-made worst cases (with and without a residual layer) and stop",
    )
    ap.add_argument(
        "--param", action="append", default=[], metavar="KEY=VALUE", help="an encoder parameter of the seeds"
    )
    args = ap.parse_args()
    params = {"num_inducing": 100}
    for kv in args.param:
        key, value = kv.split("=", 1)
        params[key] = float(value) if key == "residual" else value
    if args.worst:
        with DecodeServer() as server:
            for label, data in worst_payloads():
                o = server.decode(class_ref(Checked), {}, data, warm_with=worst_payloads()[0][1])
                print(
                    f"- {label} ({len(data):,} bytes): {o.kind} {o.message[:100]}; {o.cpu_s:.2f} s CPU, "
                    f"{o.peak_mb:.0f} MB"
                )
        return
    with DecodeServer() as server:
        r = fuzz_codec(Checked, params, cases=args.cases, seed=args.seed, server=server)
    print(f"{os.environ.get('VSGP_FUZZ_BASE', 'lwbench_plugins.vsgp')}: {r.summary()}")
    print(f"outcomes: {dict(r.outcomes)}; verdicts: {dict(r.verdicts)}; {r.seconds:.0f} s")
    kinds = Counter(v for v, _, _ in r.failures)
    for verdict, message, case in r.failures[:10]:
        print(f"- {verdict}: {message[:160]} ({len(case)} bytes)")
    print(f"(first {len(r.failures)} failures kept: {dict(kinds)})")


if __name__ == "__main__":
    main()
