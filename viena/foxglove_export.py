"""Recordings Foxglove and Lichtblick open: `viena export --format foxglove drive.mcap -o
drive-fox.mcap`, and `FoxgloveWriter` for a recorder that writes one live.

viena's own recordings keep each sample's msgpack bytes (exact replay), which Foxglove
refuses ("unsupported encoding"). These files hold, written by the Foxglove SDK's MCAP
writer, the same samples as `json` messages on `jsonschema` channels (schemas generated
from viena's own: common/json_schema.py) plus the Foxglove messages they make
(LocationFix per receiver and for the estimator, PoseInFrame, FrameTransform, Log, the
pilot's route as GeoJSON and SceneUpdate: viena/foxglove_messages.py), each at its log
time. Samples that fail their schema are counted and left out. A file is written as
`<name>.part` and takes its name once complete.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import foxglove
from foxglove.mcap import MCAPWriteOptions

from viena.common.recording import METADATA_NAME, KeyFilter, Source
from viena.foxglove_channels import FoxgloveChannels

PROFILE = "viena-foxglove"


class FoxgloveWriter:
    """`RecordingWriter`'s interface (common/recording.py), writing a Foxglove MCAP file:
    `viena record --foxglove` passes one to its Recorder instead."""

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None, part_suffix: str = ".part"):
        self.path = Path(path)
        if self.path.is_dir():
            raise IsADirectoryError(21, "is a directory", str(self.path))
        self.part = self.path.with_name(self.path.name + part_suffix)
        context = foxglove.Context()
        self._mcap = foxglove.open_mcap(self.part, allow_overwrite=True, context=context,
                                        writer_options=MCAPWriteOptions(profile=PROFILE))
        self.channels = FoxgloveChannels(context)
        self.samples = 0
        self._open = True
        if metadata:
            self.add_metadata(metadata)

    @property
    def keys(self) -> int:
        return self.channels.keys

    @property
    def messages(self) -> int:
        return self.channels.logged

    @property
    def invalid(self) -> dict[str, int]:
        return dict(self.channels.invalid)

    @property
    def size(self) -> int:
        try:
            return self.part.stat().st_size
        except OSError:
            return 0

    def write(self, key: str, encoding: str, log_time: int, data: bytes, publish_time: int | None = None) -> None:
        self.channels.publish(key, encoding, data, log_time=log_time)
        self.samples += 1

    def add_metadata(self, metadata: dict[str, str]) -> None:
        self._mcap.write_metadata(METADATA_NAME, {k: str(v) for k, v in metadata.items()})

    def flush(self) -> None:
        self._mcap.flush()

    def _finish(self) -> None:
        if self._open:
            self._open = False
            self._mcap.close()
            self.channels.close()

    def close(self) -> Path:
        """Finish the file and give it its real name."""
        self._finish()
        os.replace(self.part, self.path)
        return self.path

    def abandon(self) -> None:
        """Close; the file stays under its `.part` name."""
        try:
            self._finish()
        except Exception:
            pass

    def discard(self) -> None:
        self.abandon()
        self.part.unlink(missing_ok=True)


@dataclass
class Exported:
    path: Path
    samples: int                # samples read from the recording
    messages: int               # messages written (JSON and derived)
    invalid: dict[str, int]     # samples that failed their schema, by key


def default_output(source: str | Path) -> Path:
    source = Path(source)
    return source.with_name(source.name.removesuffix(".part").removesuffix(".mcap") + "-foxglove.mcap")


def export_foxglove(recording: Source, output: str | Path, keys: KeyFilter | None = None) -> Exported:
    output = Path(output)
    if output.resolve() == recording.path.resolve():
        raise IsADirectoryError(17, "the export needs a name of its own", str(output))
    writer = FoxgloveWriter(output)
    try:
        for msg in recording.messages(keys):
            writer.write(msg.key, msg.encoding, msg.log_time, msg.data)
        if recording.metadata:
            writer.add_metadata({**recording.metadata, "exported_from": recording.path.name})
        path = writer.close()
    except BaseException:
        writer.discard()
        raise
    return Exported(path, writer.samples, writer.messages, writer.invalid)
