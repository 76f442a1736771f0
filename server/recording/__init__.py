"""Recordings: every teaching tour and navigation task as an MCAP file, read back, replayed.

* :mod:`.store` - where recordings live on disk, their names, retention.
* :mod:`.topics` - the channels and their JSON schemas (Foxglove's well-known ones for images,
  depth, log lines and the 3D scene).
* :mod:`.messages` - what a frame, a task and a tour become in a recording (shared by the
  recorder and the replay, so both describe a step the same way).
* :mod:`.mcapfile` - one file being written, flushed after every frame.
* :mod:`.recorder` - the observer of the teaching and navigation services that writes them.
* :mod:`.reader` - reading a recording back, up to its last whole frame.
* :mod:`.replay` - ``teachrepeat replay``: the recorded frames through the server's step again.

Not part of the core: the core never imports this package (tests/unit/test_structure.py).
"""
