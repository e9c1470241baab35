"""The sensor tables a decoder may meet, handed to it -- never a process-wide registry.

A payload names its sensor in ~25 bytes: a preset (``{"preset": "vlp16"}``) or the id of a table
(``{"id": "3f2a..."}``, :meth:`lwbench.SensorModel.to_wire`); the table itself travels once per
stream (a stream file's header, ``sensor.json`` beside payloads, a link's HELLO), not in every
frame. Whoever decodes therefore knows which tables the payloads may name and hands them to the
decoder: the runner gives a fresh decoder the frame's sensor (the dataset's), ``lwbench decode``
and the link's base the stream's sensors, the conformance kit the scan's sensor::

    decoder = MyCodec(**params).use_sensors([frame.sensor])
    cloud = decoder.decode(payload)          # self.read_sensor(payload) resolves the id here

So a decode depends only on the bytes and on what the receiver was told, not on what else the
process happened to encode before (the encoder's own instance knows the sensors it wrote).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

from lwbench.sensors.model import SensorModel

__all__ = ["SensorCatalog"]


class SensorCatalog:
    """Sensor models by id (:attr:`SensorModel.sensor_id`): what a receiver was told."""

    def __init__(self, sensors: Iterable[SensorModel] = ()) -> None:
        self._by_id: dict[str, SensorModel] = {}
        self.update(sensors)

    def add(self, sensor: SensorModel) -> str:
        """Know ``sensor`` (a preset needs no entry, but may have one); returns its id."""
        if not isinstance(sensor, SensorModel):
            raise TypeError(f"a sensor catalog holds SensorModel objects, got {type(sensor).__name__}")
        self._by_id.setdefault(sensor.sensor_id, sensor)
        return sensor.sensor_id

    def update(self, sensors: Iterable[SensorModel]) -> SensorCatalog:
        for s in sensors:
            self.add(s)
        return self

    def get(self, sensor_id: str) -> SensorModel | None:
        return self._by_id.get(sensor_id)

    def __contains__(self, sensor_id: object) -> bool:
        return sensor_id in self._by_id

    def __iter__(self) -> Iterator[SensorModel]:
        return iter(self._by_id.values())

    def __len__(self) -> int:
        return len(self._by_id)

    def __repr__(self) -> str:
        return f"SensorCatalog({', '.join(self._by_id) or 'empty'})"
