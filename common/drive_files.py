"""A drive as numbered split files in a directory: the black box's writing side of the
files its readers (replay, export, plot: a drive's files read as one) share with it.

One run of a recorder is one *drive*, `viena-YYYYMMDD-HHMMSS` (UTC start; `-2`, `-3` if the
name is taken), written as `DIR/<drive>_0001.mcap`, `_0002`, ...: each a whole recording
(`.part` while open) with the metadata `drive` and `part`. A file is closed and the next
opened when it holds `split_bytes` or covers `split_s` seconds of log time, whichever
first; the next file starts with the last sample of every latched topic (topics.py
`Topic.latched`: the route's path and every process's info), logged at the file's start with its original
publish time, and says how many it starts with (metadata `repeats`), so each file replays
on its own and a reader of the whole drive skips them. After a file closes, the oldest
closed drive files in DIR are deleted until they hold at most `keep_bytes` (never the open
one: it is still `.part`). Before its first file, the writer repairs what the last run
left (`*.mcap.part`). One writer at a time per directory (a lock file): two recorders
would repair each other's open files.

Split by log time rather than the wall clock: the files say what they cover, and a test
drives the splits with the times it chooses.
"""
from __future__ import annotations

import errno
import fcntl
import logging
import os
import shutil
import threading
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

from viena.common import clock
from viena.common.recording import (
    CHUNK_BYTES,
    REPAIRING_SUFFIX,
    RecordingError,
    RecordingWriter,
    drive_file,
    drive_order,
    file_size,
    human_bytes,
    repair,
    sample_time,
)
from viena.common.samples.topics import topic_of_key

log = logging.getLogger("viena.recorder")
PART_SUFFIX = ".part"
BROKEN_SUFFIX = ".broken"
LOCK_NAME = ".viena-recorder.lock"
MB = 1_000_000

Say = Callable[[str], None]


def drive_name(directory: Path, started_ns: int) -> str:
    """`viena-YYYYMMDD-HHMMSS` of the UTC start, with `-2`, `-3`, ... if DIR holds it already."""
    base = datetime.fromtimestamp(started_ns / 1e9, UTC).strftime("viena-%Y%m%d-%H%M%S")
    taken = {p.name.partition("_")[0] for p in directory.iterdir()} if directory.is_dir() else set()
    name, n = base, 1
    while name in taken:
        n += 1
        name = f"{base}-{n}"
    return name


def file_order(path: Path) -> tuple[str, int, int]:
    """Oldest first: by start, then the `-n` of drives started in the same second, then part
    (the names are common/recording.py's DRIVE_FILE, which the readers use too)."""
    found = drive_file(path)
    if found is None:
        return (path.name, 0, 0)
    return (*drive_order(found[0]), found[1])


def drive_files(directory: Path) -> list[Path]:
    """The closed files of every drive in DIR, oldest first (a recording put there by hand,
    under another name, is not the black box's to count or delete)."""
    return sorted((p for p in directory.glob("viena-*.mcap") if drive_file(p) is not None), key=file_order)


def _kept_files(directory: Path) -> list[Path]:
    """The closed drive files and the unreadable originals kept beside their repair
    (`*.mcap.broken`), oldest first, each repair before its original: one listing."""
    found = [p for p in directory.glob("viena-*.mcap*")
             if p.name.endswith((".mcap", BROKEN_SUFFIX)) and drive_file(_closed_name(p)) is not None]
    return sorted(found, key=lambda p: (file_order(_closed_name(p)), p.name.endswith(BROKEN_SUFFIX)))


def trim_to_budget(directory: Path, keep_bytes: int, say: Say = log.info) -> list[Path]:
    """Delete the oldest closed drive files (and kept originals, `.broken`, as old as they
    are: on the SD card the budget comes first) until those left hold at most `keep_bytes`;
    one line says what went. The files deleted."""
    files = [(p, file_size(p)) for p in _kept_files(directory)]
    total = sum(size for _, size in files)
    gone: list[Path] = []
    freed = 0
    for path, size in files:
        if total <= keep_bytes:
            break
        try:
            path.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            say(f"cannot delete {path.name} to keep {directory} within {human_bytes(keep_bytes)}: "
                f"{exc.strerror or exc}")
            break
        total -= size
        freed += size
        gone.append(path)
    if gone:
        names = ", ".join(p.name for p in gone)
        say(f"deleted the {len(gone)} oldest files ({human_bytes(freed)}) to keep {directory} within "
            f"{human_bytes(keep_bytes)}: {names}")
    return gone


def _closed_name(path: Path) -> Path:
    return path.with_suffix("") if path.name.endswith(BROKEN_SUFFIX) else path


def keep_bytes_of_share(directory: Path, share: float) -> int:
    """`share` of what the drives may have: the file system's free space now plus what the
    drives in DIR already hold."""
    return int(share * (shutil.disk_usage(directory).free + sum(map(file_size, _kept_files(directory)))))


def budget_bytes(directory: Path, keep_gb: float | None, keep_share: float | None) -> int | None:
    """The drives' budget: `keep_gb` GB, else `keep_share` of the free space plus what DIR
    holds; None (no budget) when neither is given."""
    if keep_gb:
        return int(keep_gb * 1000 * MB)
    if keep_share:
        directory.mkdir(parents=True, exist_ok=True)
        return keep_bytes_of_share(directory, keep_share)
    return None


def repair_leftovers(directory: Path, say: Say = log.info) -> list[Path]:
    """Every drive file left as `.part` in DIR (a run killed or cut off) rewritten as the
    complete file it should have been. The `.part` goes only when nothing but its unfinished
    tail was lost; otherwise it stays beside the repair as `*.mcap.broken`, as does one that
    cannot be read at all. Other names (a recording someone else writes there) are not the
    black box's to touch. One line each. The files made.

    A repair cut short itself (a crash, a power cut while repairing) left a `.repairing`
    beside its `.part`: it goes first (the `.part` goes only once a repair is complete, so
    the repair is done again from it), or it would sit outside the budget for ever."""
    made: list[Path] = []
    for stale in sorted(directory.glob(f"viena-*.mcap{REPAIRING_SUFFIX}")):
        if drive_file(stale.with_suffix("")) is None:
            continue
        try:
            stale.unlink()
            say(f"deleted {stale.name}, a repair cut short (done again from its .part if it is there)")
        except OSError as exc:
            say(f"cannot delete {stale.name}, a repair cut short: {exc.strerror or exc}")
    for part in sorted(directory.glob(f"viena-*.mcap{PART_SUFFIX}")):
        if drive_file(part) is None:
            continue
        target = part.with_name(part.name[:-len(PART_SUFFIX)])
        broken = target.with_name(target.name + BROKEN_SUFFIX)
        try:
            try:
                path, samples, lost = repair(part, target)
            except RecordingError as exc:
                os.replace(part, broken)
                say(f"{part.name}, left by the last run, cannot be read ({exc}): kept as {broken.name}")
                continue
            if len(lost) > 1:                       # problems besides where it stopped: keep the evidence
                os.replace(part, broken)
                kept = f"; the original kept as {broken.name}"
            else:
                part.unlink()
                kept = ""
        except OSError as exc:
            say(f"cannot repair {part.name}, left by the last run: {exc.strerror or exc}")
            continue
        made.append(path)
        said = f" ({lost[-1]})" if lost else ""
        say(f"repaired {part.name}, left by the last run, into {path.name}: {samples} samples{said}{kept}")
    return made


class DriveWriter:
    """A SampleWriter (common/recorder.py) that writes one drive as split files into
    `directory`, with the latched repeats and the budget; `samples`, `keys` and `size` are
    the drive's, `part` the file being written.

    Opening repairs the leftovers, applies the budget and opens the first file, so a
    directory that cannot be written fails here (OSError). Write errors are raised as
    OSError, as RecordingWriter's are.
    """

    def __init__(self, directory: str | Path, *, split_bytes: int = 0, split_s: float = 0.0,
                 keep_bytes: int | None = None, metadata: dict[str, str] | None = None,
                 started_ns: int | None = None, chunk_size: int = CHUNK_BYTES, say: Say = log.info):
        self.directory = Path(directory)
        self.split_bytes, self.split_ns = split_bytes, int(split_s * 1e9)
        self.keep_bytes, self.say, self.chunk_size = keep_bytes, say, chunk_size
        self.metadata = dict(metadata or {})
        self.directory.mkdir(parents=True, exist_ok=True)
        self._lock_file = _lock(self.directory)
        self._lock = threading.Lock()         # the writing thread splits while others read `size`
        repair_leftovers(self.directory, say)
        if keep_bytes is not None:
            trim_to_budget(self.directory, keep_bytes, say)
        self.drive = drive_name(self.directory, clock.time_ns() if started_ns is None else started_ns)
        self.number = 0
        self.closed: list[Path] = []          # this drive's closed files (some may be deleted since)
        self.samples = 0
        self._closed_bytes = 0
        self._latched: dict[str, bool] = {}                          # key -> is its topic latched
        self._held: dict[tuple[str, str], tuple[int, bytes]] = {}       # last latched: publish time, data
        self._first_log_time: int | None = None                       # of the open file's new samples
        self._writer = self._open()
        self.part = self._writer.part                                 # the file being written
        self._is_open = True

    @property
    def keys(self) -> int:
        return len(self._latched)

    @property
    def size(self) -> int:
        """Bytes written in this drive so far (the open chunk not counted); from any thread."""
        with self._lock:
            return self._closed_bytes + (self._writer.size if self._is_open else 0)

    def _open(self, repeats: int = 0) -> RecordingWriter:
        self.number += 1
        path = self.directory / f"{self.drive}_{self.number:04d}.mcap"
        metadata = {**self.metadata, "drive": self.drive, "part": str(self.number), "repeats": str(repeats)}
        return RecordingWriter(path, metadata=metadata, chunk_size=self.chunk_size)

    def write(self, key: str, encoding: str, log_time: int, data: bytes) -> None:
        latched = self._latched.get(key)
        if latched is None:
            found = topic_of_key(key)
            latched = self._latched[key] = found is not None and found[0].latched
        if self._first_log_time is None:
            self._first_log_time = log_time
        elif self._full(log_time):
            self._next_file(log_time)
            self._first_log_time = log_time
        if latched:                               # kept with its publish time, for the next files
            publish_time = sample_time(data) or log_time
            self._held[(key, encoding)] = (publish_time, data)
            self._writer.write(key, encoding, log_time, data, publish_time)
        else:
            self._writer.write(key, encoding, log_time, data)
        self.samples += 1

    def _full(self, log_time: int) -> bool:
        assert self._first_log_time is not None
        return bool((self.split_bytes and self._writer.size >= self.split_bytes)
                    or (self.split_ns and log_time - self._first_log_time >= self.split_ns))

    def _next_file(self, log_time: int) -> None:
        """Close the open file, keep the budget, open the next with the latched samples,
        logged at its start (`log_time`) with their own publish times."""
        self._close_file()
        with self._lock:
            self._writer = self._open(repeats=len(self._held))
            self.part = self._writer.part
            self._is_open = True
        for (key, encoding), (publish_time, data) in self._held.items():
            self._writer.write(key, encoding, log_time, data, publish_time)

    def _close_file(self) -> Path:
        with self._lock:
            path = self._writer.close()
            self._is_open = False
            self.closed.append(path)
            self._closed_bytes += file_size(path)
        if self.keep_bytes is not None:
            trim_to_budget(self.directory, self.keep_bytes, self.say)
        return path

    def flush(self) -> None:
        self._writer.flush()

    def close(self) -> Path:
        """Close the open file (the budget kept); its path."""
        try:
            return self._close_file()
        finally:
            self._lock_file.close()

    def abandon(self) -> None:
        self._writer.abandon()
        self._lock_file.close()

    def discard(self) -> None:
        self._writer.discard()
        self._lock_file.close()


def _lock(directory: Path):
    """DIR's lock, held while this writer lives (closed with it, or by the kernel when the
    process dies); OSError if another writer holds it."""
    f = open(directory / LOCK_NAME, "a")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.close()
        raise OSError(errno.EBUSY, f"another recorder writes into {directory}") from None
    return f
