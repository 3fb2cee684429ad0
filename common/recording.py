"""Recordings: viena samples in MCAP files, written by `viena record` and read by replay,
export and plot.

Layout of a recording (https://mcap.dev/spec):

- one channel per key (and per zenoh encoding, should a key carry two): topic = the key,
  message encoding `msgpack` (`json` for JSON text), schema named after the encoding's
  suffix (`viena.sim.truth/1`), and the zenoh encoding itself in the channel metadata
  (`zenoh_encoding`) so that replay restores it exactly;
- log time = when the sample arrived at the recorder (UTC ns, steady: wall clock at the
  start plus a monotonic clock), publish time = the sample's own `t` when it has one;
- zstd-compressed chunks with CRCs, so that damage is detected rather than decoded.

Reading is forgiving on purpose: a recording cut short (recorder killed, disk full) or
damaged is read as far as it can be. A damaged chunk is skipped and the reading goes on;
a broken file structure ends it. `Recording.problems` and `Recording.stopped` say what
happened and where, in bytes and in seconds into the drive.

The black box splits a drive into numbered files (`viena-20260501-101203_0001.mcap`, ...),
each one replayable alone; `Drive` reads them as one, and `open_source` turns what a
person names (a file, a directory, a drive id) into what to read.
"""
from __future__ import annotations

import json
import os
import re
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
from mcap.exceptions import EndOfFile, McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Metadata
from mcap.records import Schema as McapSchema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from viena.common import clock
from viena.common.errors import InputError, SampleError
from viena.common.paths import drives_dir
from viena.common.samples.topics import topic_of_key
from viena.common.schema import MSGPACK, unpack

MCAP_MAGIC = b"\x89MCAP0\r\n"
ENCODING_KEY = "zenoh_encoding"
#: channel metadata from the table of topics (common/samples/topics.py): the topic's name,
#: and "true" when its last sample holds for the whole drive (a file split off a drive
#: repeats it at its start)
TOPIC_KEY = "viena_topic"
LATCHED_KEY = "viena_latched"
PROFILE = "viena"
METADATA_NAME = "viena.recording"
#: small chunks: a recorder that dies loses at most this much (about 2 s of the whole car)
CHUNK_BYTES = 256 * 1024
#: no record of ours is near this; a corrupted length field must not allocate gigabytes
_RECORD_LIMIT = 256 * 1024 * 1024
_MESSAGE_ENCODINGS = {MSGPACK: "msgpack", "application/json": "json"}
_ZENOH_ENCODINGS = {v: k for k, v in _MESSAGE_ENCODINGS.items()}


class RecordingError(InputError):
    """A file that cannot be read as a recording at all."""


def message_encoding(zenoh_encoding: str) -> str:
    """MCAP message encoding of a zenoh encoding: 'application/msgpack;x/1' -> 'msgpack'."""
    base = zenoh_encoding.split(";", 1)[0]
    return _MESSAGE_ENCODINGS.get(base, base)


def schema_name(zenoh_encoding: str) -> str:
    """The schema suffix of a zenoh encoding ('' when it has none)."""
    return zenoh_encoding.split(";", 1)[1] if ";" in zenoh_encoding else ""


#: msgpack map headers by first byte: how long the header is
_MAP_HEADER = {**{b: 1 for b in range(0x80, 0x90)}, 0xDE: 3, 0xDF: 5}
#: msgpack unsigned and signed 64-bit integers, as the samples' `t` is packed
_INT64 = {0xCF: struct.Struct(">Q"), 0xD3: struct.Struct(">q")}


def sample_time(data: bytes) -> int | None:
    """A msgpack sample's own `t` (int ns), read without unpacking the rest of it: at once
    when `t` is the map's first key as a 64-bit integer (the samples' own packing), else by
    skipping key by key."""
    header = _MAP_HEADER.get(data[0]) if data else None
    if header is None:
        return None
    if data[header:header + 2] == b"\xa1t" and len(data) >= header + 11:
        int64 = _INT64.get(data[header + 2])
        if int64 is not None:
            t = int64.unpack_from(data, header + 3)[0]
            return t if t >= 0 else None
    unpacker = msgpack.Unpacker(raw=False)
    unpacker.feed(data)
    try:
        for _ in range(unpacker.read_map_header()):
            if unpacker.unpack() == "t":
                t = unpacker.unpack()
                return t if type(t) is int and 0 <= t < 1 << 64 else None
            unpacker.skip()
    except Exception:       # garbage is the recording's business, not the recorder's
        return None
    return None


def topic_metadata(key: str) -> dict[str, str]:
    """What the table of topics says of a recorded key (viena/<car>/...): {} for a key it
    does not know."""
    found = topic_of_key(key)
    if found is None:
        return {}
    return {TOPIC_KEY: found[0].name, LATCHED_KEY: "true" if found[0].latched else "false"}


def decode_value(data: bytes, encoding: str) -> Any:
    """A payload as Python values: msgpack or JSON text; SampleError if it is neither."""
    kind = message_encoding(encoding)
    if kind == "json" or (kind != "msgpack" and data[:1] in (b"{", b"[")):
        try:
            return json.loads(data)
        except ValueError as exc:
            raise SampleError(f"not valid JSON: {exc}") from None
    return unpack(data)


class ReceiveClock:
    """UTC ns that never steps: the wall clock once, then a monotonic clock.

    Replay derives its timing from log times, so an NTP step during a drive must not
    become a pause or a burst.
    """

    def __init__(self):
        self._wall0 = clock.time_ns()
        self._mono0 = clock.monotonic_ns()

    def __call__(self) -> int:
        return self._wall0 + clock.monotonic_ns() - self._mono0


@dataclass(frozen=True, slots=True)
class Recorded:
    """One sample as recorded."""

    key: str
    encoding: str           # the zenoh encoding it arrived with
    log_time: int           # ns UTC, when it arrived
    publish_time: int       # ns UTC, the sample's own `t` (log time if it had none)
    data: bytes

    @property
    def schema(self) -> str:
        return schema_name(self.encoding)

    def value(self) -> Any:
        return decode_value(self.data, self.encoding)


class RecordingWriter:
    """Writes samples into `<path>.part`; `close()` finishes the MCAP file and renames it
    to `path`, so that a file under its real name is always complete.

    Write errors (full disk, file size limit) are raised as OSError; then `abandon()`
    leaves the `.part` file, readable up to its last whole chunk, under its `.part` name.
    """

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None,
                 chunk_size: int = CHUNK_BYTES, part_suffix: str = ".part"):
        self.path = Path(path)
        if self.path.is_dir():
            raise IsADirectoryError(21, "is a directory", str(self.path))
        self.part = self.path.with_name(self.path.name + part_suffix)
        self._file = open(self.part, "wb")
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._channels: dict[tuple[str, str], list[int]] = {}     # -> [channel id, sequence]
        self._schemas: dict[str, int] = {}
        self.samples = 0
        self._writer.start(profile=PROFILE, library="viena record")
        if metadata:
            self.add_metadata(metadata)

    @property
    def keys(self) -> int:
        return len({key for key, _ in self._channels})

    @property
    def size(self) -> int:
        """Bytes written so far (what is still in the open chunk is not counted)."""
        return self._file.tell()

    def write(self, key: str, encoding: str, log_time: int, data: bytes,
              publish_time: int | None = None) -> None:
        channel = self._channels.get((key, encoding))
        if channel is None:
            channel = self._channels[(key, encoding)] = [self._register(key, encoding), 0]
        channel[1] = (channel[1] + 1) & 0xFFFFFFFF
        if publish_time is None:
            publish_time = sample_time(data) or log_time
        self._writer.add_message(channel[0], log_time, data, publish_time, channel[1])
        self.samples += 1

    def _register(self, key: str, encoding: str) -> int:
        name = schema_name(encoding)
        schema_id = 0
        if name:
            schema_id = self._schemas.get(name) or self._writer.register_schema(name, "", b"")
            self._schemas[name] = schema_id
        return self._writer.register_channel(key, message_encoding(encoding), schema_id,
                                             {ENCODING_KEY: encoding, **topic_metadata(key)})

    def add_metadata(self, metadata: dict[str, str]) -> None:
        self._writer.add_metadata(METADATA_NAME, {k: str(v) for k, v in metadata.items()})

    def flush(self) -> None:
        """Close the open chunk and make the file durable up to here: a reader (ours or
        mcap's own) then sees everything written so far, even if the process dies next."""
        self._writer.flush()
        os.fsync(self._file.fileno())

    def close(self) -> Path:
        """Finish the file, make it durable, and give it its real name."""
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self.part, self.path)
        return self.path

    def abandon(self) -> None:
        """Close without finishing: the `.part` file stays as the evidence it is."""
        try:
            self._file.close()
        except OSError:
            pass

    def discard(self) -> None:
        """Close and remove: nothing was recorded worth keeping."""
        self.abandon()
        self.part.unlink(missing_ok=True)


class KeyFilter:
    """Which keys to keep: any key included by one of the key expressions (all if none)."""

    def __init__(self, patterns: Iterable[str] | None = None):
        import zenoh

        self._exprs = []
        for pattern in patterns or ():
            try:
                self._exprs.append(zenoh.KeyExpr(pattern))
            except Exception as exc:
                raise InputError(f"{pattern!r} is not a key expression ({exc})") from None
        self._cache: dict[str, bool] = {}

    def __call__(self, key: str) -> bool:
        if not self._exprs:
            return True
        keep = self._cache.get(key)
        if keep is None:
            keep = self._cache[key] = any(e.includes(key) for e in self._exprs)
        return keep


class Recording:
    """A recording, read as far as it can be read.

    Iterate `messages()`; afterwards `problems` lists what was skipped, `stopped` says
    where reading ended early (None when the file was read to its end), and `complete`
    is true when the file was closed properly by its recorder.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            self.size = self.path.stat().st_size
            with open(self.path, "rb") as f:
                magic = f.read(len(MCAP_MAGIC))
        except OSError as exc:
            raise RecordingError(f"{self.path}: {exc.strerror}") from None
        if magic != MCAP_MAGIC:
            raise RecordingError(f"{self.path}: {'empty file' if not magic else 'not an MCAP file'}")
        self.metadata: dict[str, str] = {}
        self.problems: list[str] = []
        self.stopped: str | None = None
        self.complete = False
        self.count = 0
        self.first_log_time: int | None = None
        self.last_log_time: int | None = None
        self._channels: dict[int, tuple[str, str]] = {}
        self._schemas: dict[int, str] = {}

    def messages(self, keys: KeyFilter | None = None) -> Iterator[Recorded]:
        """Every readable sample in file order, for the keys `keys` keeps."""
        self.problems, self.stopped, self.complete, self.count = [], None, False, 0
        orphans = 0
        try:
            f = open(self.path, "rb")
        except OSError as exc:
            raise RecordingError(f"{self.path}: {exc.strerror}") from None
        with f:
            self._read_summary(f)
            f.seek(0)
            for offset, record in self._records(f):
                for r in self._unchunked(offset, record):
                    if not isinstance(r, Message):
                        self._define(r)
                        continue
                    channel = self._channels.get(r.channel_id)
                    if channel is None:
                        orphans += 1
                        continue
                    self._seen(r.log_time)
                    if keys is None or keys(channel[0]):
                        yield Recorded(channel[0], channel[1], r.log_time, r.publish_time, r.data)
        if orphans:
            self.problems.append(f"{orphans} samples skipped: their channel was defined in a "
                                 f"damaged part of the file")

    def _records(self, f) -> Iterator[tuple[int, object]]:
        """Top-level records with their byte offsets, up to the end or the first one that
        cannot be read (then `stopped` says where and why)."""
        records = StreamReader(f, emit_chunks=True, record_size_limit=_RECORD_LIMIT).records
        offset = 0
        while True:
            try:
                record = next(records)
            except StopIteration:
                self.complete = True
                return
            except EndOfFile:
                self._stop(offset, "the file ends here without its closing records (the recorder "
                                   "did not finish: killed, or the disk filled)"
                           if offset >= self.size else "the file ends inside a record (cut short)")
                return
            except (McapError, struct.error, ValueError, UnicodeDecodeError) as exc:
                self._stop(offset, f"unreadable record ({_describe(exc)})")
                return
            yield offset, record
            offset = f.tell()

    def _unchunked(self, offset: int, record) -> list:
        """A chunk's records (none if it is damaged: noted in `problems`), or the record."""
        if not isinstance(record, Chunk):
            return [record]
        try:
            return breakup_chunk(record, validate_crc=True)
        except Exception as exc:          # zstd, CRC, struct: all mean a damaged chunk
            self.problems.append(f"{self._where(offset)}: damaged chunk skipped ({_describe(exc)})")
            return []

    def _read_summary(self, f) -> None:
        """Channels from the summary of a complete file: they survive a damaged chunk."""
        try:
            summary = make_reader(f).get_summary()
        except Exception:
            return                                    # no summary: learnt while reading
        if summary is not None:
            for schema in summary.schemas.values():
                self._define(schema)
            for channel in summary.channels.values():
                self._define(channel)

    def _define(self, record) -> None:
        if isinstance(record, McapSchema):
            self._schemas[record.id] = record.name
        elif isinstance(record, Channel):
            encoding = record.metadata.get(ENCODING_KEY)
            if encoding is None:                      # a recording made by another tool
                base = _ZENOH_ENCODINGS.get(record.message_encoding, record.message_encoding)
                name = self._schemas.get(record.schema_id, "")
                encoding = f"{base};{name}" if name else base
            self._channels[record.id] = (record.topic, encoding)
        elif isinstance(record, Metadata) and record.name == METADATA_NAME:
            self.metadata = dict(record.metadata)

    def _seen(self, log_time: int) -> None:
        self.count += 1
        if self.first_log_time is None or log_time < self.first_log_time:
            self.first_log_time = log_time
        if self.last_log_time is None or log_time > self.last_log_time:
            self.last_log_time = log_time

    def _where(self, offset: int) -> str:
        where = f"byte {offset} of {self.size}"
        if self.first_log_time is not None and self.last_log_time is not None:   # set together in _seen
            where += f", {(self.last_log_time - self.first_log_time) / 1e9:.3f} s into the recording"
        return where

    def _stop(self, offset: int, why: str) -> None:
        self.stopped = f"stopped at {self._where(offset)} after {self.count} samples: {why}"

    def report(self) -> list[str]:
        """What a person should know after reading: problems, then where it stopped."""
        return [*self.problems, *([self.stopped] if self.stopped else [])]


def _describe(exc: Exception) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def human_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


#: what a repair writes until it is complete (beside the `.part` it reads)
REPAIRING_SUFFIX = ".repairing"


def repair(path: str | Path, output: str | Path | None = None) -> tuple[Path, int, list[str]]:
    """Rewrite a recording cut short (`drive.mcap.part` after a kill -9 or a power cut) as a
    complete MCAP file that any reader opens: every sample that can still be read, its
    channels and metadata, a fresh summary. Returns (the new file, samples, what was lost)."""
    source = Recording(path)
    path = Path(path)
    if output is None:
        output = path.with_name(path.name[:-len(".part")]) if path.name.endswith(".part") \
            else path.with_name(path.stem + "-repaired.mcap")
    output = Path(output)
    if output.resolve() == path.resolve():
        raise RecordingError(f"{output}: the repaired recording needs a name of its own")
    writer = RecordingWriter(output, part_suffix=REPAIRING_SUFFIX)     # not the .part being read
    try:
        for m in source.messages():
            writer.write(m.key, m.encoding, m.log_time, m.data, m.publish_time)
        if source.metadata:
            writer.add_metadata({**source.metadata, "repaired_from": path.name})
        done = writer.close()
    except BaseException:
        writer.discard()
        raise
    return done, writer.samples, source.report()


#: a drive's files (one run of the recorder, split): DIR/<drive>_<NNNN>.mcap, `.part` while open,
#: NNNN from 0001, <drive> = viena-YYYYMMDD-HHMMSS (the run's UTC start) with -2, -3, ... if the name was taken
DRIVE_ID = re.compile(r"viena-\d{8}-\d{6}(?:-\d+)?")
DRIVE_FILE = re.compile(rf"(?P<drive>{DRIVE_ID.pattern})_(?P<number>\d{{4,}})\.mcap(?P<open>\.part)?")


def drive_file(path: str | Path) -> tuple[str, int] | None:
    """(drive id, file number) of a drive's file name; None for any other name."""
    found = DRIVE_FILE.fullmatch(Path(path).name)
    return None if found is None else (found["drive"], int(found["number"]))


def find_drives(directory: str | Path) -> dict[str, list[Path]]:
    """The drives in `directory`, oldest first: id -> its files in order. A file both closed
    and `.part` (a repair cut short) counts once, closed."""
    drives: dict[str, dict[int, Path]] = {}
    try:
        paths = sorted(Path(directory).iterdir())
    except OSError as exc:
        raise RecordingError(f"{directory}: {exc.strerror}") from None
    for path in paths:
        found = drive_file(path)
        if found is not None:
            files = drives.setdefault(found[0], {})
            if found[1] not in files or not path.name.endswith(".part"):
                files[found[1]] = path
    return {d: [files[n] for n in sorted(files)] for d, files in sorted(drives.items(), key=_drive_order)}


def _drive_order(item: tuple[str, object]) -> tuple[str, int]:
    return drive_order(item[0])


def drive_order(drive_id: str) -> tuple[str, int]:
    """Oldest first: by start, then the `-n` of drives started in the same second (-2 before -10)."""
    start = len("viena-YYYYMMDD-HHMMSS")
    return drive_id[:start], int(drive_id[start + 1:] or 1)


class Drive:
    """One run of the recorder, read as one recording: its numbered files in order.

    The same reading interface as `Recording` (messages, problems, stopped, complete,
    count, first and last log time, metadata, report), so replay, export and info take
    either. File n > 1 opens with the latched topics' last samples, as many as its
    metadata `repeats` says; they are skipped here (in a file that does not say: any
    message logged at or before the last one read from the files before it), so each
    sample comes once and the log times run on across files. A file read alone has them.
    """

    def __init__(self, drive_id: str, files: list[Path], note: str | None = None):
        if not files:
            raise RecordingError(f"drive {drive_id}: no files")
        self.id, self.files, self.note = drive_id, list(files), note
        self.path = self.files[0].parent / drive_id
        self.metadata: dict[str, str] = {}
        self.problems: list[str] = []
        self.stopped: str | None = None
        self.complete = False
        self.count = 0
        self.repeats = 0
        self.first_log_time: int | None = None
        self.last_log_time: int | None = None

    @classmethod
    def in_directory(cls, directory: str | Path, drive_id: str | None = None) -> Drive:
        """The drive `drive_id` of `directory`, else its only one, else its newest (`note`
        then says which, and how to pick another)."""
        drives = find_drives(directory)
        if drive_id is not None:
            if drive_id not in drives:
                have = ", ".join(drives) or "none"
                raise RecordingError(f"{directory}: no drive {drive_id} (drives there: {have})")
            return cls(drive_id, drives[drive_id])
        if not drives:
            raise RecordingError(f"{directory}: no drive in it (files named viena-YYYYMMDD-HHMMSS_NNNN.mcap)")
        newest = list(drives)[-1]
        note = None if len(drives) == 1 else (
            f"{directory} holds {len(drives)} drives: reading the newest, {newest} (--drive ID for another; "
            f"`viena record list {directory}` lists them)")
        return cls(newest, drives[newest], note)

    @property
    def size(self) -> int:
        return sum(file_size(p) for p in self.files)

    @property
    def cut_short(self) -> bool:
        """Its last file is still `.part`: being written, or the recorder stopped without closing it."""
        return self.files[-1].name.endswith(".part")

    def messages(self, keys: KeyFilter | None = None) -> Iterator[Recorded]:
        """Every readable sample of every file, in order, each once."""
        self.metadata, self.problems, self.stopped = {}, [], None
        self.count, self.repeats, self.first_log_time, self.last_log_time = 0, 0, None, None
        stops: list[str] = []
        complete = True
        for number, path in enumerate(self.files):
            try:
                recording = Recording(path)
            except RecordingError as exc:
                self.problems.append(str(exc))
                complete = False
                continue
            after = self.last_log_time if number else None
            yield from self._new(recording, keys, after)
            self._took(recording)
            complete = complete and recording.complete
            self.problems.extend(f"{path.name}: {line}" for line in recording.problems)
            if recording.stopped:
                stops.append(f"{path.name}: {recording.stopped}")
        self.stopped = "; ".join(stops) or None
        self.complete = complete and not self.cut_short

    def _new(self, recording: Recording, keys: KeyFilter | None, after: int | None) -> Iterator[Recorded]:
        """A later file's messages (`after`: the last log time read before it; None for the
        first file) without its repeats: as many as its metadata `repeats` says, or, in a
        file that does not say, those logged at or before `after`. For the keys `keys`
        keeps; the key filter comes after the repeat test: what repeats is the file's."""
        skip: int | None = None
        for i, m in enumerate(recording.messages()):
            if after is not None:
                if skip is None:
                    skip = int(recording.metadata.get("repeats", -1))
                if (i < skip) if skip >= 0 else (m.log_time <= after):
                    self.repeats += 1
                    continue
            self.count += 1
            if self.first_log_time is None:
                self.first_log_time = m.log_time
            if self.last_log_time is None or m.log_time > self.last_log_time:
                self.last_log_time = m.log_time
            if keys is None or keys(m.key):
                yield m

    def _took(self, recording: Recording) -> None:
        if not self.metadata and recording.metadata:
            self.metadata = {k: v for k, v in recording.metadata.items() if k != "part"}

    def report(self) -> list[str]:
        """What a person should know after reading: problems, then where files stopped."""
        return [*self.problems, *([self.stopped] if self.stopped else [])]


#: what replay, export and info read: one file, or a drive of several as one
Source = Recording | Drive


def file_size(path: Path) -> int:
    """A file's size; 0 for one gone meanwhile (a budget deleting it) or unreadable."""
    try:
        return path.stat().st_size
    except OSError:
        return 0


def open_source(target: str | Path, drive_id: str | None = None,
                say: Callable[[str], object] | None = None) -> Source:
    """What a tool was asked to read: a file means that file alone (`.mcap` or `.mcap.part`);
    a directory means a whole drive in it (`drive_id`, its only one, or its newest: then
    `say` is told which); a drive id (`viena-20260501-101203`, or DIR/viena-20260501-101203)
    means that whole drive."""
    path = Path(target)
    if path.is_dir():
        drive = Drive.in_directory(path, drive_id)
        if drive.note and say is not None:
            say(drive.note)
        return drive
    if not path.exists() and DRIVE_ID.fullmatch(path.name):
        directory = path.parent if str(path.parent) != "." or find_drives(".") else drives_dir()
        return Drive.in_directory(directory, path.name)
    if drive_id is not None:
        raise RecordingError(f"{target}: --drive picks a drive in a directory; this is one file")
    return Recording(path)
