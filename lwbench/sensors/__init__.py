"""Sensor models: a spinning LiDAR's beams and azimuth grid (:mod:`.model`), the datasheets of real
sensors (:mod:`.specs`), the tables a receiver is told (:mod:`.catalog`), and a model derived from
a scan when no one says (:mod:`.derive`, from a beam table, the point order or a guess:
:mod:`.beam_table`, :mod:`.beam_order`, :mod:`.beam_guess`). Public names come through ``lwbench``."""
