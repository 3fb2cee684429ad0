"""What of the corrections a receiver is sent: only what it can decode, never more than its
serial line carries. Pure (the time is given), so the rules are tested without a port.

- RTCM 3 (format RTCMV3) is split into frames (rtcm3.py); a frame whose message number the
  receiver does not decode (MSM, GLONASS, ...: an OEM4 decodes 1001-1006) is dropped before
  it takes the line, counted by number;
- the line's budget: `baud / 10` bytes a second (start, 8 data and stop bits) less a margin
  for the commands, as a bucket that holds `burst_s` of it; a unit (a frame; for the other
  formats, which are written as they come, a piece of a sample no larger than the bucket:
  RAW has no frames to keep whole) the bucket cannot hold now is dropped whole: a flood from
  the caster costs corrections, never the line;
- a sample in the wrong format (RTCM 3 frames when the receiver was set to take RTCM 2.x,
  CMR or RTCA) is dropped whole.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from viena.common.rtcm3 import MAX_FRAME, Rtcm3Framer

#: Share of the line kept free for the commands (and the line's own slack).
LINE_MARGIN = 0.1
#: How much the bucket holds, in seconds of the line.
BURST_S = 1.0
#: Drop reasons, as the health counters name them (corrections_dropped_<reason>, in bytes).
#: "internal": a writer step that raised (a bug: logged with its traceback).
DROP_REASONS = ("type", "flood", "format", "garbage", "not_ready", "queue", "port", "internal")


def line_bytes_per_s(baud: int, margin: float = LINE_MARGIN) -> float:
    """What the corrections may use of a serial line at `baud`."""
    return baud / 10.0 * (1.0 - margin)


class LineBudget:
    """A token bucket of bytes, filled at the line's rate."""

    def __init__(self, bytes_per_s: float, burst_s: float = BURST_S):
        self.rate = float(bytes_per_s)
        # a whole frame must fit, however slow the line
        self.capacity = max(self.rate * burst_s, float(MAX_FRAME))
        self._tokens = self.capacity
        self._t: float | None = None

    def take(self, n: int, now_s: float) -> bool:
        """Spend `n` bytes at `now_s` if the bucket has them."""
        if self._t is not None:
            self._tokens = min(self.capacity, self._tokens + self.rate * max(0.0, now_s - self._t))
        self._t = now_s
        if n > self._tokens:
            return False
        self._tokens -= n
        return True


@dataclass
class Taken:
    """What one sample gave: the bytes to write, and what is new to say about it."""

    data: bytes = b""
    frames: int = 0
    new_dropped_types: list[int] = field(default_factory=list)   # first time each is dropped
    flooded: bool = False            # a unit did not fit the line
    wrong_format: bool = False


@dataclass
class FeedCounts:
    samples: int = 0
    bytes_in: int = 0
    bytes_written: int = 0
    frames_written: int = 0
    dropped: Counter = field(default_factory=Counter)          # bytes by reason
    dropped_types: Counter = field(default_factory=Counter)    # frames by message number


class CorrectionsFeed:
    """One receiver's corrections: `take(data, sample_format, now_s)` is what to write;
    `wrote(taken)` once it is written (or `drop("port", n)` when the port failed)."""

    def __init__(self, fmt: str, decodes: frozenset[int] | None, bytes_per_s: float,
                 burst_s: float = BURST_S):
        self.format = fmt
        #: the RTCM 3 message numbers the receiver decodes (None: all)
        self.decodes = decodes
        self.budget = LineBudget(bytes_per_s, burst_s)
        self.splitter = Rtcm3Framer()
        self.counts = FeedCounts()

    def drop(self, reason: str, n: int) -> None:
        """Count `n` bytes dropped for a reason the feed does not see (not ready, queue full)."""
        self.counts.dropped[reason] += n

    def restart(self) -> None:
        """A new stream begins (another port, another start-up): the partial frame the
        framer held is dropped, counted as garbage."""
        self.counts.dropped["garbage"] += self.splitter.reset()

    def unaccounted(self) -> int:
        """Bytes in that are neither written, dropped nor waiting in the framer (0 unless a
        step failed half way)."""
        c = self.counts
        return max(0, c.bytes_in - c.bytes_written - sum(c.dropped.values()) - self.splitter.pending)

    def take(self, data: bytes, sample_format: str, now_s: float) -> Taken:
        c = self.counts
        c.samples += 1
        c.bytes_in += len(data)
        if self.format != "RTCMV3":
            if sample_format == "RTCMV3":
                c.dropped["format"] += len(data)
                return Taken(wrong_format=True)
            return self._take_raw(data, now_s)
        skipped = self.splitter.garbage_bytes
        frames = self.splitter.feed(data)
        c.dropped["garbage"] += self.splitter.garbage_bytes - skipped
        out, taken = bytearray(), Taken()
        for frame in frames:
            if self.decodes is not None and frame.type not in self.decodes:
                if frame.type not in c.dropped_types:
                    taken.new_dropped_types.append(frame.type)
                c.dropped_types[frame.type] += 1
                c.dropped["type"] += len(frame.data)
            elif not self.budget.take(len(frame.data), now_s):
                c.dropped["flood"] += len(frame.data)
                taken.flooded = True
            else:
                out += frame.data
                taken.frames += 1
        taken.data = bytes(out)
        return taken

    def _take_raw(self, data: bytes, now_s: float) -> Taken:
        """Bytes of a format without frames here (RTCM 2.x, RTCA, CMR): in pieces the bucket
        can hold, each taking the budget, so a burst read larger than the bucket is not lost
        whole when the line carries it on average."""
        piece = max(1, int(self.budget.capacity))
        out, taken = bytearray(), Taken()
        for i in range(0, len(data), piece):
            part = data[i:i + piece]
            if self.budget.take(len(part), now_s):
                out += part
            else:
                self.counts.dropped["flood"] += len(part)
                taken.flooded = True
        taken.data = bytes(out)
        return taken

    def wrote(self, taken: Taken) -> None:
        """`taken` went to the port."""
        self.counts.bytes_written += len(taken.data)
        self.counts.frames_written += taken.frames
