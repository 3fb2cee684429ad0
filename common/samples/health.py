"""viena.health/1 on viena/<car>/<service>[/<unit>]/health (1 Hz): what a service tells the
world about how it is doing, the names device services report under, and how a person reads
it. The counters a service keeps and turns into this sample: common/health.py."""
from __future__ import annotations

from dataclasses import dataclass, field

from viena.common.display import Alert, fields_line, fmt_age, fmt_map, number
from viena.common.schema import F, Schema

HEALTH = Schema("viena.health/1", {
    "t": F.time,
    "seq": F.int,
    "service": F.str,
    "unit": F.optional(F.str),
    "uptime_s": F.float,
    "rates_hz": F.map,            # events per second over the last period, by name
    "counts": F.map,              # totals since start, by name
    "errors": F.map,              # error totals since start, by name
    "last_sample_age_s": F.optional(F.float),
    "state": F.optional(F.map),   # anything else the service wants seen (connected, ...)
})

# What every device service reports about its device, under these names and no others: the
# device supervisor (common/supervisor.py) keeps them, the monitor reads them.
RECONNECTS = "reconnects"               # counts: the device came back after it was lost
CONNECT_FAILURES = "connect_failures"   # errors: an attempt to open or start it failed
PORT_FAILURES = "port_failures"         # errors: the open port failed (unplugged, I/O error)
SILENCES = "silences"                   # errors: it said nothing for its silence timeout
INTERNAL_ERRORS = "internal_errors"     # errors: handling it raised (a bug); it was reopened
DEVICE_ERRORS = (CONNECT_FAILURES, PORT_FAILURES, SILENCES, INTERNAL_ERRORS)
CONNECTED = "connected"                 # state: True while it is open and being served
LAST_ERROR = "last_error"               # state: why it was last lost or not reached
PORT = "port"                           # state: its URL


def _numbers(v) -> dict[str, float]:
    if not isinstance(v, dict):
        return {}
    return {str(k): n for k, x in v.items() if (n := number(x)) is not None}


@dataclass(frozen=True)
class HealthReport:
    """A health sample as a person reads it, from anything that came on a health key."""

    uptime_s: float | None = None               # as of now: reported, plus the sample's age
    rates_hz: dict = field(default_factory=dict)    # of events that happened at least once
    errors: dict = field(default_factory=dict)      # the error totals that are not zero
    last_sample_age_s: float | None = None      # as reported (the sample's age says how old)
    reconnects: int | None = None               # device services count them (RECONNECTS)
    state: dict = field(default_factory=dict)

    @classmethod
    def of(cls, sample, age_s: float = 0.0) -> HealthReport:
        """The report in `sample` (any value), received `age_s` ago."""
        if not isinstance(sample, dict):
            return cls()
        uptime_s = number(sample.get("uptime_s"))
        counts = _numbers(sample.get("counts"))
        reconnects = counts.get(RECONNECTS)
        state = sample.get("state")
        return cls(
            uptime_s=None if uptime_s is None else uptime_s + age_s,
            # a rate of something that never happened (unknown_messages 0.0) is only noise
            rates_hz={k: v for k, v in _numbers(sample.get("rates_hz")).items() if v or counts.get(k)},
            errors={k: v for k, v in _numbers(sample.get("errors")).items() if v},
            last_sample_age_s=number(sample.get("last_sample_age_s")),
            reconnects=None if reconnects is None else int(reconnects),
            state=state if isinstance(state, dict) else {})

    def cells(self) -> dict[str, str]:
        """How the monitor shows it, one cell per column."""
        return {
            "up": fmt_age(self.uptime_s),
            "rates Hz": fmt_map(self.rates_hz),
            "errors": Alert(fmt_map(self.errors, 0)) if self.errors else "-",
            "last sample": fmt_age(self.last_sample_age_s),
            "reconnects": "-" if self.reconnects is None else str(self.reconnects),
            "state": fields_line(self.state),
        }


def monitor_view(sample, age_s: float = 0.0) -> dict[str, str]:
    """How the monitor shows a health sample received `age_s` ago."""
    return HealthReport.of(sample, age_s).cells()
