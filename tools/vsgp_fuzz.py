"""vsgp's hand-made worst payloads (issue 23): the most expensive payloads the decoder's bounds
let through, decoded in the fuzz decode server -- CPU time and peak memory against the fuzz
contract's 1 s and 512 MB (docs/vsgp.md, "bounded decode").

    python tools/vsgp_fuzz.py

Each payload is built by hand from the plugin's wire format (many tiles, as many inducing points
a tile as the work budget admits, the shortest lengthscales, the general kernel path; then the
same with the fullest residual layer a sensor admits). The mutation campaign that used to live
here is ``lwbench fuzz vsgp [--param residual=0.1]``. A development script (not installed): it
needs the plugin's internals to build the payloads and core's decode server (``lwbench.fuzz``)
to measure them as the fuzz contract does -- a plugin may import neither core module.
"""

from __future__ import annotations

import argparse

import numpy as np


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
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.parse_args()
    from lwbench import codec_class
    from lwbench.fuzz import DecodeServer, class_ref

    ref = class_ref(codec_class("vsgp"))
    payloads = worst_payloads()
    with DecodeServer() as server:
        for label, data in payloads:
            o = server.decode(ref, {}, data, warm_with=payloads[0][1])
            print(
                f"- {label} ({len(data):,} bytes): {o.kind} {o.message[:100]}; {o.cpu_s:.2f} s CPU, "
                f"{o.peak_mb:.0f} MB -- {o.verdict}"
            )


if __name__ == "__main__":
    main()
