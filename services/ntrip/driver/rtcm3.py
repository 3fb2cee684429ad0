"""RTCM 3 frames out of a caster's byte stream, batched per read: what one sample on
gnss/corrections carries (the frames are cut and checked by viena.common.rtcm3)."""
from __future__ import annotations

from dataclasses import dataclass, field

from viena.common.rtcm3 import Rtcm3Framer as _Frames


@dataclass
class Batch:
    """What one read brought: its whole checked frames, in order."""

    data: bytes = b""
    types: list[int] = field(default_factory=list)
    #: the reference station named by the last frame of the batch that names one
    base_id: str | None = None
    #: bytes skipped in this read (not part of any checked frame)
    garbage_bytes: int = 0


class Rtcm3Framer(_Frames):
    """The shared framer, each read's frames joined into one Batch."""

    def feed_batch(self, data: bytes) -> Batch:
        garbage = self.garbage_bytes
        frames = self.feed(data)
        base_id = None
        for frame in frames:
            station = frame.station_id
            if station is not None:
                base_id = str(station)
        return Batch(b"".join(f.data for f in frames), [f.type for f in frames], base_id,
                     self.garbage_bytes - garbage)
