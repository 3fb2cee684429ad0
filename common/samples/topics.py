"""The car's topics, declared once: key pattern, schema, producer, rate, reliability.

Every key lives under ``viena/<car>/``; a pattern's ``{unit}`` or ``{service}`` is one key
chunk. The services build their keys here (`Keys.of(topics.GNSS_FIX, unit="gnss0")`), and
the tools read the table to know what a key is: the monitor picks a panel and a view, ``viena
list`` and ``viena info`` show the nominal rate beside the measured one, the Foxglove bridge
finds the schema, the recorder knows which keys describe the whole drive (``latched``).
dora's ``dataflow.yml`` and a ROS message package are the models: one place a newcomer
reads to see what flows where.

    >>> GNSS_FIX.key(unit="gnss0")
    'gnss/gnss0/fix'
    >>> GNSS_FIX.key()                         # any unit
    'gnss/*/fix'
    >>> HEALTH.key(service="sim")              # its own, or any unit's: sim has none
    'sim/**/health'
    >>> topic_of("gnss/gnss1/fix")
    (Topic('gnss.fix'), {'unit': 'gnss1'})
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from enum import StrEnum

from viena.common.samples import corrections, estimator, fix, health, imu, info, ntrip, pilot, steering, truth
from viena.common.schema import Schema

#: every key of every car starts with ROOT/<car>/
ROOT = "viena"
_CHUNK = re.compile(r"\{(\w+)\}")


class Kind(StrEnum):
    """How a key is used."""
    PUT = "put"                               # a stream of samples
    QUERY = "query"                           # a command: asked, answered by its one server
    QUERY_OR_PUT = "query or put"             # a command also taken as a put (no answer)
    TOKEN = "liveliness token"                # held while a process runs


class Congestion(StrEnum):
    """zenoh's congestion control for a publisher: a stale sample is worth less than a
    stalled publisher (DROP), except where every message counts (BLOCK)."""
    DROP = "drop"
    BLOCK = "block"


@dataclass(frozen=True)
class Topic:
    """One row of the table."""

    name: str                                 # how code and docs call it: "gnss.fix"
    pattern: str                              # after viena/<car>/: "gnss/{unit}/fix"
    kind: Kind
    schema: Schema | None                     # None: a command's map, see `payload`
    producer: str                             # the process that publishes or answers it
    rate: str                                 # as a person says it
    nominal_hz: float | None = None           # the sim car's default rate; None: on demand
    reliability: str = "reliable"             # zenoh's transport: every topic is reliable
    congestion: Congestion = Congestion.DROP
    latched: bool = False                     # its last sample stays true for the whole drive
    payload: str = ""                         # for commands: the payload, where it is parsed
    consumers: tuple[str, ...] = ()
    optional: tuple[str, ...] = ()            # placeholders a key may leave out
    retired: tuple[str, ...] = ()             # its schema's earlier names (a version bumped)
    view: object = field(default=None, repr=False, compare=False)     # its monitor view
    read: object = field(default=None, repr=False, compare=False)     # its typed reader, where it has one

    def __repr__(self) -> str:
        return f"Topic({self.name!r})"

    @property
    def chunks(self) -> tuple[str, ...]:
        """The pattern's placeholders, in order: ("unit",) for gnss/{unit}/fix."""
        return tuple(_CHUNK.findall(self.pattern))

    def key(self, **chunks: str | None) -> str:
        """The key after viena/<car>/: each placeholder filled from `chunks`. One not given is
        any chunk (`*`), or any number of chunks (`**`) where it is `optional` (a service
        without units has none); an `optional` one given as None is left out (this
        process's own key, for a service without units)."""
        unknown = set(chunks) - set(self.chunks)
        if unknown:
            raise TypeError(f"{self.name} has no {', '.join(sorted(unknown))} in {self.pattern!r}")
        parts = []
        for part in self.pattern.split("/"):
            m = _CHUNK.fullmatch(part)
            if m is None:
                parts.append(part)
                continue
            name, optional = m[1], m[1] in self.optional
            value = chunks.get(name, "**" if optional else "*")
            if value is None:
                if not optional:
                    raise ValueError(f"{self.name}: {name} cannot be left out of {self.pattern!r}")
                continue
            if not value or "/" in value:
                raise ValueError(f"{name} of {self.name} must be one key chunk, got {value!r}")
            parts.append(value)
        return "/".join(parts)

    def match(self, relative_key: str) -> dict[str, str] | None:
        """The placeholders' values if `relative_key` (after viena/<car>/) is one of this
        topic's keys; None if not. An `optional` placeholder may be absent (sim/health)."""
        got = relative_key.split("/")
        for form in self._forms():
            if len(form) != len(got):
                continue
            values: dict[str, str] = {}
            for g, w in zip(got, form):
                m = _CHUNK.fullmatch(w)
                if m is not None:
                    values[m[1]] = g
                elif g != w:
                    break
            else:
                return values
        return None

    def _forms(self) -> list[list[str]]:
        parts = self.pattern.split("/")
        short = [p for p in parts if not ((m := _CHUNK.fullmatch(p)) and m[1] in self.optional)]
        return [parts, short] if short != parts else [parts]


_COMMAND = "a map, parsed by services/steering/model/requests.py (docs/steering.md#commands)"

SIM_TRUTH = Topic("sim.truth", "sim/truth", Kind.PUT, truth.TRUTH, "viena-sim", "100 Hz", 100.0,
                  consumers=("monitor", "record", "tests and benches"), view=truth.monitor_view)
GNSS_FIX = Topic("gnss.fix", "gnss/{unit}/fix", Kind.PUT, fix.FIX, "viena-gnss",
                 "the receiver's: 20 Hz (NovAtel BESTXYZ ONTIME 0.05), 10 Hz (NMEA)", 20.0,
                 consumers=("viena-estimator", "viena-steering", "viena-ntrip", "monitor", "record"),
                 view=fix.monitor_view, read=fix.read_fix)
GNSS_CORRECTIONS = Topic("gnss.corrections", "gnss/corrections", Kind.PUT, corrections.CORRECTIONS,
                         "viena-ntrip", "one sample per read from the caster, about 1 Hz", 1.0,
                         consumers=("viena-gnss", "monitor", "record"), view=corrections.monitor_view,
                         read=corrections.read_corrections)
NTRIP_STATE = Topic("ntrip.state", "ntrip/state", Kind.PUT, ntrip.STATE, "viena-ntrip",
                    "1 Hz and at every change", 1.0, consumers=("monitor", "foxglove", "record"),
                    view=ntrip.monitor_view, read=ntrip.read_state)
IMU_SAMPLE = Topic("imu.sample", "imu/{unit}/sample", Kind.PUT, imu.SAMPLE, "viena-imu",
                   "the firmware's: about 82.5 Hz (VIENA), 50 Hz (stock Razor AHRS)", 82.5,
                   consumers=("viena-estimator", "monitor", "record"), view=imu.monitor_view,
                   read=imu.read_sample)
STEERING_STATE = Topic("steering.state", "steering/state", Kind.PUT, steering.STATE, "viena-steering",
                       "`state_rate_hz`, 50 Hz", 50.0,
                       consumers=("viena-pilot", "viena-sim", "monitor", "record", "plot"),
                       view=steering.monitor_view)
STEERING_ARM = Topic("steering.arm", "steering/arm", Kind.QUERY, None, "viena-steering", "on demand",
                     payload=_COMMAND, consumers=("viena-pilot", "viena-steer", "zenoh CLI"))
STEERING_SETPOINT = Topic("steering.setpoint", "steering/setpoint", Kind.QUERY_OR_PUT, None, "viena-steering",
                          "at least every `watchdog_s` (0.5 s) while armed", payload=_COMMAND,
                          consumers=("viena-pilot", "viena-steer", "zenoh CLI"))
STEERING_CALIBRATION = Topic("steering.calibration", "steering/calibration", Kind.QUERY, None, "viena-steering",
                             "on demand", payload=_COMMAND, consumers=("viena-steer", "zenoh CLI"))
STEERING_ESTOP = Topic("steering.estop", "steering/estop", Kind.QUERY_OR_PUT, None, "viena-steering",
                       "on demand", congestion=Congestion.BLOCK,      # a stop is never dropped
                       payload="anything: an e-stop is never refused for its form",
                       consumers=("anyone with a session: pilot, monitor, foxglove, observer",))
ESTIMATOR_STATE = Topic("estimator.state", "estimator/state", Kind.PUT, estimator.STATE, "viena-estimator",
                        "after every IMU sample used (after every fix when there is no IMU)", 82.5,
                        retired=("viena.estimator.state/1",),      # roll and pitch renamed (issue 13)
                        consumers=("viena-pilot", "viena-steering", "monitor", "record", "plot", "export"),
                        view=estimator.monitor_view)
PILOT_ROUTE = Topic("pilot.route", "pilot/route", Kind.QUERY_OR_PUT, None, "viena-pilot", "on demand",
                    payload="a route: GeoJSON, points, CSV or Titans checkpoints (docs/pilot.md#routes)",
                    consumers=("viena route", "zenoh CLI"))
PILOT_CMD = Topic("pilot.cmd", "pilot/cmd", Kind.QUERY_OR_PUT, None, "viena-pilot", "on demand",
                  payload='{"cmd": "start"} or {"cmd": "stop"}', consumers=("viena pilot", "zenoh CLI"))
PILOT_STATE = Topic("pilot.state", "pilot/state", Kind.PUT, pilot.STATE, "viena-pilot", "20 Hz", 20.0,
                    consumers=("monitor", "record", "plot"), view=pilot.monitor_view)
PILOT_PATH = Topic("pilot.path", "pilot/path", Kind.PUT, pilot.PATH, "viena-pilot",
                   "when taken, then every 5 s", 0.2, latched=True, consumers=("foxglove", "record", "plot"))
HEALTH = Topic("health", "{service}/{unit}/health", Kind.PUT, health.HEALTH, "every process", "1 Hz", 1.0,
               optional=("unit",), consumers=("monitor", "viena doctor", "foxglove", "record"),
               view=health.monitor_view, read=health.HealthReport.of)
INFO = Topic("info", "{service}/{unit}/info", Kind.PUT, info.INFO, "every process", "at start, then every 10 s",
             0.1, latched=True, optional=("unit",), consumers=("monitor", "record", "foxglove"),
             view=info.monitor_view)
ALIVE = Topic("alive", "alive/{service}/{unit}", Kind.TOKEN, None, "every process", "while the process runs",
              optional=("unit",),
              consumers=("monitor", "viena list", "a second process of the same name, which refuses to start"))

#: every topic, in the order docs/dataflow.md lists them
TOPICS: tuple[Topic, ...] = (
    SIM_TRUTH, GNSS_FIX, GNSS_CORRECTIONS, NTRIP_STATE, IMU_SAMPLE, STEERING_STATE, STEERING_ARM,
    STEERING_SETPOINT, STEERING_CALIBRATION, STEERING_ESTOP, ESTIMATOR_STATE, PILOT_ROUTE, PILOT_CMD,
    PILOT_STATE, PILOT_PATH, HEALTH, INFO, ALIVE)
BY_NAME: dict[str, Topic] = {t.name: t for t in TOPICS}
#: the topic each schema travels on (health's schema on every service's health key)
BY_SCHEMA: dict[str, Topic] = {t.schema.name: t for t in TOPICS if t.schema is not None}
#: schemas no longer published, by name -> the topic that carried them (older recordings hold them)
RETIRED: dict[str, Topic] = {name: t for t in TOPICS for name in t.retired}
#: the topics of every process ({service}/{unit}/...): matched after all the others
CATCH_ALL = (ALIVE, HEALTH, INFO)
#: the steering's commands, in the order a pilot uses them
STEERING_COMMANDS = (STEERING_ARM, STEERING_SETPOINT, STEERING_CALIBRATION, STEERING_ESTOP)


def topic_of(relative_key: str) -> tuple[Topic, dict[str, str]] | None:
    """The topic a key (after viena/<car>/) belongs to, and its placeholders' values; None for
    a key the table does not know (a tool's own, or a newer car's)."""
    for topic in TOPICS:
        if topic in CATCH_ALL:
            continue
        values = topic.match(relative_key)
        if values is not None:
            return topic, values
    for topic in CATCH_ALL:                  # the catch-all patterns last
        values = topic.match(relative_key)
        if values is not None:
            return topic, values
    return None


def topic_of_key(key: str) -> tuple[Topic, dict[str, str]] | None:
    """`topic_of` for a whole key, viena/<car>/..., of any car."""
    parts = key.split("/", 2)
    return topic_of(parts[2]) if len(parts) == 3 and parts[0] == ROOT else None


def unit_in(chunks: dict[str, str]) -> str:
    """The unit a key names (its `{unit}`), "" for a service without units."""
    return chunks.get("unit", "")


def process_name(chunks: dict[str, str]) -> str:
    """The process a health or liveliness key belongs to, as people name it: "gnss/gnss0", "sim"."""
    return "/".join(c for c in (chunks.get("service", ""), unit_in(chunks)) if c)


def markdown_table() -> str:
    """The table as docs/dataflow.md#key-expressions shows it (checked against the doc by
    tests/test_topics.py)."""
    rows = ["| key (after `viena/<car>/`) | kind | schema or payload | producer | rate |",
            "|---|---|---|---|---|"]
    for t in TOPICS:
        what = f"`{t.schema.name}`" if t.schema is not None else (t.payload or "-")
        rows.append(f"| `{t.pattern}` | {t.kind} | {what} | {t.producer} | {t.rate} |")
    return "\n".join(rows)
