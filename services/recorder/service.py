"""`viena-recorder`: the black box. Every key of the car, always, from the moment the router
is up, into a drive of numbered MCAP files (services/recorder/README.md):

    viena-recorder --directory /var/lib/viena/drives --split-mb 64 --split-s 600 --keep-gb 8
    viena-recorder --config compose/pi.toml           # the [recorder] table

At start it listens at once (the samples queue), repairs what the last run left (`.part`
files: a power cut), trims the oldest closed files to the budget, then writes. Each file
closes after `split_mb` or `split_s`, opens with the last sample of every latched topic
(the route held), and is made durable every half second. A full disk or a card gone
read-only stops the recording with one line in the log and a red health
(`write_failures`); the rest of the car never waits for it: zenoh keeps the samples (a
ring: the oldest go if the writer falls far behind), one thread takes them a batch at a
time and writes.
"""
from __future__ import annotations

import socket
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from viena.common import clock
from viena.common.config import use_one_thread_runtime
from viena.common.drive_files import MB, DriveWriter, budget_bytes
from viena.common.errors import ConfigError
from viena.common.paths import drives_dir
from viena.common.recorder import Recorder
from viena.common.service import Service, run_service
from viena.common.settings import setting

#: how often the health says which file is being written and how big the drive is
STATE_PERIOD_S = 1.0


@dataclass(frozen=True)
class RecorderSettings:
    """[recorder]: the black box."""
    directory: str = setting("", "where the drives go (default $VIENA_DRIVES, else ~/.local/share/viena/drives)",
                             metavar="DIR")
    split_mb: float = setting(64.0, "a new file after this many MB (0: no size limit)")
    split_s: float = setting(600.0, "a new file after this many seconds of samples (0: no time limit)")
    keep_gb: float = setting(0.0, "keep at most this many GB of closed files, the oldest deleted first "
                                  "(0: `keep_share` decides)")
    keep_share: float = setting(0.5, "with keep_gb 0: at most this share of the free space at start, plus "
                                     "what the directory holds")
    keyexprs: tuple[str, ...] = setting(("**",), "what to record, key expressions after viena/<car>/")


class RecorderService(Service):
    name = "recorder"
    settings_class = RecorderSettings

    def __init__(self, args):
        super().__init__(args)
        # its own samples (the health) reach it on its own session, not through the router:
        # with timestamping on, zenoh stamps them here, so they too keep their arrival time
        self.zenoh_config.insert_json5("timestamping/enabled", "true")

    def start(self) -> None:
        s = self.settings
        directory = Path(s.directory).expanduser() if s.directory else drives_dir()
        if not 0.0 < s.keep_share <= 1.0:
            raise ConfigError(f"[recorder] keep_share: a share of the free space, 0 < F <= 1, got {s.keep_share!r}")
        keyexprs = [self.keys.key(k) for k in s.keyexprs]
        metadata = {"keyexprs": " ".join(keyexprs), "car": self.keys.car, "host": socket.gethostname(),
                    "started": datetime.fromtimestamp(clock.time(), UTC).isoformat(timespec="seconds")}
        # the car is recorded from now on, queued while the last run's file is repaired: the
        # writer comes below, once that is done
        self.recorder = Recorder(self.session, keyexprs, None, on_error=self._failed,  # type: ignore[arg-type]
                                 batched=True)
        self.recorder.listen()
        try:
            directory.mkdir(parents=True, exist_ok=True)
            keep = budget_bytes(directory, s.keep_gb, s.keep_share)
            self.writer = DriveWriter(directory, split_bytes=int(s.split_mb * MB), split_s=s.split_s,
                                      keep_bytes=keep, metadata=metadata, say=self.log.info)
        except OSError as exc:             # a card gone read-only, full, or another recorder there
            self.recorder.unlisten()
            self._red(exc, f"cannot record into {directory}: {exc.strerror or exc} (the car goes on "
                           "without its black box)")
            return
        self.health.set("directory", str(directory))
        self.health.set("drive", self.writer.drive)
        self.health.set("keep_bytes", keep)
        self.recorder.writer = self.writer
        self.recorder.start()
        self._reporter = clock.Thread(target=self._report, name="recorder-state", daemon=True)
        self._reporter.start()
        self.log.info("recording %s into %s (drive %s; files of %g MB or %g s; budget %.2f GB)",
                      " ".join(keyexprs), directory, self.writer.drive, s.split_mb, s.split_s, (keep or 0) / 1e9)

    def _failed(self, exc: OSError) -> None:
        """From the writing thread, once: the recording stops, the car goes on."""
        self._red(exc, f"cannot write {self.writer.part}: {exc.strerror or exc}: recording stopped (the car "
                       "goes on; free the disk and restart the recorder)")

    def _red(self, exc: OSError, line: str) -> None:
        """One line in the log, and the health red (`write_failures`) until a restart."""
        self.health.error("write_failures")
        self.health.set("recording", False)
        self.health.set("last_error", str(exc.strerror or exc))
        self.log.error("%s", line)

    def _report(self) -> None:
        """Once a second, not once a sample: the samples written (their rate is the health's),
        and where they go."""
        written = dropped = 0
        while not self.stopping.wait(STATE_PERIOD_S):
            try:
                written = self._say_state(written)
                dropped = self._say_dropped(dropped)
            except Exception:                   # the health must go on saying what it can
                self.log.exception("the recorder's state could not be read")

    def _say_state(self, written: int) -> int:
        samples = self.recorder.samples
        if samples > written:
            self.health.count("samples", samples - written)
            self.health.mark_sample()
        self.health.set("recording", not self.recorder.failed.is_set())
        self.health.set("file", self.writer.part.name)
        self.health.set("drive_bytes", self.writer.size)
        self.health.set("backlog", self.recorder.backlog())
        return samples

    def _say_dropped(self, said: int) -> int:
        """`possibly_dropped` (red): a take in which a ring was full, so zenoh may have let
        the oldest go (the writer fell RING_SAMPLES behind)."""
        dropped = self.recorder.possibly_dropped
        if dropped > said:
            self.health.error("possibly_dropped", dropped - said)
        return dropped

    def stop(self) -> None:
        recorder = getattr(self, "recorder", None)
        if recorder is not None and recorder.writer is None:
            recorder.unlisten()
        elif recorder is not None:
            path = recorder.stop()
            if path is not None:
                self.log.info("closed %s: drive %s, %d samples", path.name, self.writer.drive, recorder.samples)


def main(argv=None) -> int:
    use_one_thread_runtime()             # it only takes samples in: 20 % less CPU so
    return run_service(RecorderService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
