"""The NTRIP client's driver: the retry policy (the 10 s rule over thousands of random
histories), RTCM 3 framing, chunked streams, the credentials file, pygnssutils' request and
answer pieces, the connection loop on a virtual clock, and real connections to the caster's
twin (v1, v2, TLS, and every way a caster says no)."""
from __future__ import annotations

import base64
import logging
import os
import stat

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyrtcm import RTCMReader
from pyrtcm.rtcmhelpers import crc2bytes
from vienatest import free_port, wait_until

from viena.common import clock
from viena.common.lockstep.scheduler import VirtualClock
from viena.common.rtcm3 import STATION_ID_TYPES
from viena.services.ntrip.driver.caster import CasterAddress, Dechunker, LinkError, fetch_sourcetable
from viena.services.ntrip.driver.client import ClientConfig, NtripClient, RateWindow
from viena.services.ntrip.driver.credentials import Credentials, CredentialsError, read_credentials
from viena.services.ntrip.driver.protocol import NtripProtocol, Position
from viena.services.ntrip.driver.retry import TOLERANCE_S, RetryPolicy
from viena.services.ntrip.driver.rtcm3 import Rtcm3Framer
from viena.services.ntrip.driver.sourcetable import by_distance, mountpoints
from viena.services.ntrip.simulator.caster import CasterTwin, Mountpoint
from viena.services.ntrip.simulator.timebase import Timebase

MIN_S = 10.0


def frame(number: int, station: int = 0, length: int = 19) -> bytes:
    """An RTCM 3 frame of `number` naming `station` (zeros after), CRC by pyrtcm."""
    payload = (number << 12 | station).to_bytes(3, "big") + bytes(length - 3)
    head = bytes([0xD3, length >> 8 & 3, length & 0xFF]) + payload
    return head + crc2bytes(head)


# -- the retry policy --------------------------------------------------------------------------
def test_failures_back_off_10_10_20_40_then_the_cap():
    policy, now, waits = RetryPolicy(MIN_S, 60.0), 0.0, []
    for _ in range(7):
        now += policy.wait_s(now)
        policy.started(now)
        now += 0.1                                      # refused at once
        policy.ended(now)
        waits.append(round(policy.next_start() - now, 6))
    assert waits == [10.0, 10.0, 20.0, 40.0, 60.0, 60.0, 60.0]


def test_a_long_stream_allows_an_attempt_at_once_and_resets_the_backoff():
    policy = RetryPolicy(MIN_S, 60.0)
    for t in (0.0, 10.1, 20.2):                         # three failures: 10, 10, then 20 s
        policy.started(t)
        policy.ended(t + 0.1)
    assert policy.next_start() == pytest.approx(20.3 + 20.0)
    policy.started(40.3)
    policy.ended(400.0, streamed_s=350.0)               # the caster served 350 s, then restarted
    assert policy.next_start() == 400.0 and policy.failures == 0
    policy.started(400.0)
    policy.ended(400.5, streamed_s=0.4)                 # dropped at once: a failure like any other
    assert policy.next_start() == pytest.approx(410.5) and policy.failures == 1


def test_an_attempt_before_its_time_is_refused():
    policy = RetryPolicy(MIN_S)
    policy.started(100.0)
    policy.ended(130.0, streamed_s=25.0)                # streamed 25 s (> 10): at once
    policy.started(130.0)
    with pytest.raises(RuntimeError, match="too early"):
        policy.started(139.9)


def test_the_cap_is_never_under_the_minimum_interval():
    assert RetryPolicy(MIN_S, 3.0).max_interval_s == MIN_S


# each attempt: (how long it lasted, how long it streamed (a fraction of it), how late the
# caller started it after it was allowed)
ATTEMPTS = st.lists(st.tuples(st.floats(0.0, 400.0), st.floats(0.0, 1.0), st.floats(0.0, 30.0)),
                    min_size=1, max_size=60)


@settings(max_examples=2000, deadline=None)
@given(ATTEMPTS, st.floats(10.0, 300.0))
def test_never_two_attempts_less_than_10_s_apart_and_never_waits_beyond_the_cap(attempts, cap):
    policy, now, starts = RetryPolicy(MIN_S, cap), 0.0, []
    for duration, streamed_part, late in attempts:
        wait = policy.wait_s(now)
        assert wait <= max(cap, MIN_S) + 1e-9
        now += wait + late
        policy.started(now)
        starts.append(now)
        streamed = duration * streamed_part
        now += duration
        policy.ended(now, streamed)
        if streamed > MIN_S:
            assert policy.wait_s(now) == 0.0            # a good stream: again at once
    assert all(b - a >= MIN_S - TOLERANCE_S for a, b in zip(starts, starts[1:]))


def woken_start(policy: RetryPolicy, now_ns: int) -> float:
    """The attempt the client's loop makes at `now_ns` on the lockstep clock: it waits as
    the policy says, wakes at a whole nanosecond, and reads monotonic() as ns / 1e9."""
    wake_ns = now_ns + round(policy.wait_s(now_ns / 1e9) * 1e9)
    policy.started(wake_ns / 1e9)
    return wake_ns / 1e9


def test_a_wake_a_rounding_short_of_the_allowed_time_may_start():
    """The review's case: the wake lands one ulp before last start + 10 s."""
    policy, last_ns = RetryPolicy(MIN_S), 57_613_775_900
    policy.started(last_ns / 1e9)
    policy.ended(last_ns / 1e9 + 0.001)
    policy.failures = 0                                 # only the 10 s start-to-start rule
    start = woken_start(policy, 64_411_329_046)
    assert start < policy.next_start() + TOLERANCE_S and start - last_ns / 1e9 >= MIN_S - TOLERANCE_S


@settings(max_examples=3000, deadline=None)
@given(st.integers(0, 10**15), st.lists(st.tuples(st.integers(0, 400 * 10**9), st.integers(0, 30 * 10**9),
                                                  st.booleans()), min_size=1, max_size=20))
def test_wakes_rounded_to_the_nanosecond_never_break_the_policy(first_ns, attempts):
    """Each attempt: how long it lasted, how long the loop took to look again, whether it
    streamed; all in ns, as the lockstep clock counts."""
    policy, now_ns, starts = RetryPolicy(MIN_S), first_ns, []
    for duration_ns, late_ns, streamed in attempts:
        starts.append(woken_start(policy, now_ns))
        now_ns = round(starts[-1] * 1e9) + duration_ns
        policy.ended(now_ns / 1e9, duration_ns / 1e9 if streamed else 0.0)
        now_ns += late_ns % (round(policy.wait_s(now_ns / 1e9) * 1e9) + 1)   # wakes before it is allowed, too
    assert all(b - a >= MIN_S - TOLERANCE_S for a, b in zip(starts, starts[1:]))


# -- RTCM 3 framing ----------------------------------------------------------------------------
def test_frames_come_whole_and_checked_however_the_reads_split_them():
    stream = frame(1005, 2050) + frame(1004, 2050, 120) + frame(1019, 0, 61) + frame(1074, 2050, 200)
    for cut in range(1, len(stream)):
        framer = Rtcm3Framer()
        a, b = framer.feed_batch(stream[:cut]), framer.feed_batch(stream[cut:])
        assert a.data + b.data == stream
        assert a.types + b.types == [1005, 1004, 1019, 1074]
        assert framer.garbage_bytes == 0 and framer.pending == 0


def test_one_batch_per_read_with_its_types_and_base_station():
    framer = Rtcm3Framer()
    batch = framer.feed_batch(frame(1005, 77) + frame(1004, 77, 80) + frame(1019) + frame(1033, 78, 30))
    assert batch.types == [1005, 1004, 1019, 1033] and batch.base_id == "78"
    assert framer.frames == 4


def test_the_station_id_is_the_one_pyrtcm_reads():
    for number in (1004, 1005, 1006, 1033, 1074, 1084, 1230):
        f = frame(number, 1234, 60)
        assert number in STATION_ID_TYPES
        assert Rtcm3Framer().feed_batch(f).base_id == str(RTCMReader.parse(f).DF003) == "1234"
    assert 1019 not in STATION_ID_TYPES and Rtcm3Framer().feed_batch(frame(1019, 99, 61)).base_id is None


def test_garbage_is_counted_never_passed_on_and_swallows_no_frame():
    good = [frame(1005, 5), frame(1004, 5, 90), frame(1074, 5, 150)]
    # garbage that fools a reader looking for every protocol: a false 0xD3 with a length,
    # SPARTN's 's', NMEA's '$G', UBX's header, and a frame whose CRC is wrong
    bad_frame = bytearray(frame(1004, 5, 40))
    bad_frame[10] ^= 0xFF
    junk = [b"\xd3\x00\x40garbage", b"s\x01\x02$GPGGA,1,2", b"\xb5\x62\x01\x07\xff\xff", bytes(bad_frame)]
    stream = b"".join(j + g for j, g in zip(junk, good + [b""]))
    framer = Rtcm3Framer()
    out = framer.feed_batch(stream)
    framer.reset()
    assert out.data == b"".join(good) and out.types == [1005, 1004, 1074]
    assert framer.garbage_bytes == sum(map(len, junk)) and out.garbage_bytes + len(bad_frame) >= sum(map(len, junk)) - 1
    assert framer.crc_errors >= 1


# -- chunked streams -----------------------------------------------------------------------------
def test_chunked_streams_undone_however_the_reads_split_them():
    payload = [frame(1005, 1), b"", frame(1004, 1, 300), bytes(range(256)) * 3]
    body = b"".join(b"%x\r\n%s\r\n" % (len(p), p) for p in payload if p) + b"0\r\n\r\n"
    for cut in range(1, len(body), 7):
        d = Dechunker()
        assert d.feed(body[:cut]) + d.feed(body[cut:]) == b"".join(payload)
        assert d.done


def test_a_broken_chunked_stream_is_an_error():
    with pytest.raises(ValueError):
        Dechunker().feed(b"zz\r\nabc\r\n")
    with pytest.raises(ValueError):
        Dechunker().feed(b"3\r\nabcXY")


# -- the credentials file -------------------------------------------------------------------------
def write(path, text, mode):
    path.write_text(text)
    os.chmod(path, mode)
    return path


def test_credentials_read_from_a_file_only_its_owner_reads(tmp_path):
    creds = read_credentials(write(tmp_path / "c", "# the caster's login\nuser:pa:ss word\n", 0o600))
    assert creds == Credentials("user", "pa:ss word")
    assert "pa:ss" not in repr(creds) and "pa:ss" not in str(creds)


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o660])
def test_a_credentials_file_others_can_read_is_refused_in_one_line(tmp_path, mode):
    path = write(tmp_path / "c", "user:secret\n", mode)
    with pytest.raises(CredentialsError) as err:
        read_credentials(path)
    message = str(err.value)
    assert "\n" not in message and f"chmod 600 {path}" in message and f"{mode:04o}" in message
    assert "secret" not in message


@pytest.mark.parametrize("text", ["", "justauser\n", ":nouser\n", "a:b\nc:d\n"])
def test_a_credentials_file_that_is_not_one_login_is_refused_without_showing_it(tmp_path, text):
    with pytest.raises(CredentialsError, match="must hold one line user:password") as err:
        read_credentials(write(tmp_path / "c", text, 0o600))
    assert all(part not in str(err.value) for part in ("justauser", "nouser", "a:b"))


def test_a_password_keeps_the_spaces_at_its_ends(tmp_path):
    for ending in ("\n", "\r\n", ""):
        creds = read_credentials(write(tmp_path / "c", f"  user: pass word {ending}", 0o600))
        assert creds == Credentials("user", " pass word ")


def test_a_symlinked_credentials_file_is_refused(tmp_path):
    real = write(tmp_path / "real", "user:secret\n", 0o600)
    (tmp_path / "link").symlink_to(real)
    with pytest.raises(CredentialsError, match="is a symlink: give the file itself") as err:
        read_credentials(tmp_path / "link")
    assert "secret" not in str(err.value) and read_credentials(real) == Credentials("user", "secret")


def test_a_fifo_in_place_of_the_credentials_file_is_refused_not_waited_on(tmp_path):
    os.mkfifo(tmp_path / "fifo", 0o600)
    with pytest.raises(CredentialsError, match="is not a file"):
        read_credentials(tmp_path / "fifo")


def test_a_missing_credentials_file_says_what_to_write(tmp_path):
    with pytest.raises(CredentialsError, match="does not exist: write one line user:password"):
        read_credentials(tmp_path / "none")


# -- the request and the answer (pygnssutils' pieces) ---------------------------------------------
HERE = Position(38.7369, -9.1427, 120.0, kind="fixed", sats=9, hdop=0.8)


def test_v2_request_carries_version_login_and_the_gga_header():
    text = NtripProtocol().request("caster.example", 2101, "NEAR0", "2.0", Credentials("u", "p"), HERE).decode()
    lines = text.split("\r\n")
    assert lines[0] == "GET /NEAR0 HTTP/1.1" and "Host: caster.example:2101" in lines
    assert "Ntrip-Version: Ntrip/2.0" in lines and any(x.startswith("User-Agent: NTRIP ") for x in lines)
    assert f"Authorization: Basic {base64.b64encode(b'u:p').decode()}" in lines
    gga = next(x for x in lines if x.startswith("Ntrip-GGA: "))[len("Ntrip-GGA: "):]
    assert gga.startswith("$GPGGA,") and ",3844.21400,N,00908.56200,W,4,9,0.8,120.0,M," in gga
    assert text.endswith("\r\n\r\n")


def test_v1_request_sends_the_gga_after_it_and_an_open_caster_gets_no_login():
    text = NtripProtocol().request("c", 2101, "NEAR0", "1.0", None, HERE).decode()
    head, gga = text.split("\r\n\r\n")
    assert head.startswith("GET /NEAR0 HTTP/1.0") and "Ntrip-Version" not in head
    assert "Authorization" not in head and gga.startswith("$GPGGA,") and gga.endswith("\r\n")


@pytest.mark.parametrize("header, stream, table, chunked", [
    (b"ICY 200 OK", True, False, False),
    (b"HTTP/1.1 200 OK\r\nContent-Type: gnss/data\r\nTransfer-Encoding: chunked", True, False, True),
    (b"HTTP/1.0 200 OK\r\nContent-Type: application/octet-stream", True, False, False),
    (b"SOURCETABLE 200 OK\r\nContent-Type: text/plain", False, True, False),
    (b"HTTP/1.1 200 OK\r\nContent-Type: gnss/sourcetable", False, True, False),
    (b"HTTP/1.1 200 OK\r\nContent-Type: text/html; charset=UTF-8", False, False, False),
    (b"HTTP/1.1 401 Unauthorized\r\nWWW-Authenticate: Basic realm=\"x\"", False, False, False),
])
def test_answers_are_told_apart(header, stream, table, chunked):
    answer = NtripProtocol().answer(header)
    assert (answer.is_stream, answer.is_sourcetable, answer.chunked) == (stream, table, chunked)


def test_an_answer_that_is_not_http_is_a_value_error():
    with pytest.raises(ValueError):
        NtripProtocol().answer(b"<html><body>hello")


def test_the_protocol_leaves_the_rtcm_loggers_as_they_were():
    logger = logging.getLogger("pyrtcm")
    before = (logger.level, list(logger.handlers))
    NtripProtocol()
    assert (logger.level, list(logger.handlers)) == before


def test_mountpoints_sorted_by_distance():
    table = NtripProtocol().sourcetable(
        "SOURCETABLE 200 OK\r\n"
        "STR;FAR;Porto;RTCM 3.2;1004(1),1005(10);2;GPS+GLO;NET;PRT;41.15;-8.61;0;0;sNTRIP;none;B;N;9600;\r\n"
        "STR;NEAR;Lisboa;RTCM 3.1;1004(1);2;GPS;NET;PRT;38.74;-9.14;1;1;sNTRIP;none;B;N;4800;\r\n"
        "STR;NOWHERE;?;CMR;;0;GPS;NET;PRT;;;0;0;x;none;N;N;;\r\n"
        "ENDSOURCETABLE\r\n")
    ordered = by_distance(mountpoints(table), 38.7369, -9.1427)
    assert [m.name for m, _ in ordered] == ["NEAR", "FAR", "NOWHERE"]
    assert ordered[0][1] < 1.0 and 270 < ordered[1][1] < 285 and ordered[2][1] is None
    assert ordered[0][0].wants_gga and ordered[0][0].network and ordered[1][0].nav_systems == "GPS+GLO"


def test_rate_is_over_the_last_ten_seconds():
    r = RateWindow(10.0)
    for t in range(30):
        r.add(float(t), 100)
    assert r.rate(29.5) == pytest.approx(100.0) and r.rate(100.0) == 0.0


# -- the connection loop on a virtual clock ---------------------------------------------------------
class ScriptedCaster:
    """Stands for the network: each attempt takes the next behaviour of the script, then
    the last one for ever. ("fail", LinkError, seconds it takes), ("stream", seconds of data,
    then "drop" or "silent")."""

    def __init__(self, *script):
        self.script, self.starts, self.positions = list(script), [], []

    def open(self, config, credentials, position, protocol):
        self.starts.append(clock.monotonic())
        self.positions.append(position)
        step = self.script.pop(0) if len(self.script) > 1 else self.script[0]
        if step[0] == "fail":
            clock.sleep(step[2])
            raise step[1]
        return FakeLink(clock.monotonic() + step[1], step[2])


class FakeLink:
    def __init__(self, data_until, then):
        self.data_until, self.then, self.sent = data_until, then, []

    def read(self, timeout_s):
        if clock.monotonic() < self.data_until:
            clock.sleep(min(0.2, timeout_s))
            return frame(1005, 42) + b"xx"
        if self.then == "drop":
            raise LinkError("caster closed the stream", "dropped")
        clock.sleep(timeout_s)
        return None

    def send(self, data):
        self.sent.append(data)

    def close(self):
        pass


def run_client(script, seconds, **config):
    caster = ScriptedCaster(*script)
    batches = []
    with VirtualClock(watchdog_s=10.0) as vc:
        cfg = ClientConfig(CasterAddress("caster", 2101, "MP"), **config)
        client = NtripClient(cfg, on_batch=batches.append, open_link=caster.open).start()
        vc.run_for(seconds)
        status = client.status()
        client.stop()
        vc.run_for(2.0)
    return caster, client, status, batches


REFUSED = LinkError("connection refused", "connection_refused")
UNAUTHORIZED = LinkError("401 Unauthorized: check the credentials file", "unauthorized", refused=True)
SLOW = LinkError("no answer from caster:2101 in 10 s", "unreachable")


def gaps(starts):
    return [round(b - a, 3) for a, b in zip(starts, starts[1:])]


def test_a_caster_that_refuses_is_tried_10_10_20_40_then_every_60_s():
    caster, client, status, _ = run_client([("fail", REFUSED, 0.0)], 400.0)
    assert gaps(caster.starts)[:6] == [10.0, 10.0, 20.0, 40.0, 60.0, 60.0]
    assert status["state"] == "waiting" and status["why"] == "connection refused"
    assert 0 < status["next_attempt_s"] <= 60 and client.errors["connection_refused"] == len(caster.starts)


def test_a_401_is_refused_with_its_reason_and_still_retried_slowly():
    caster, client, status, _ = run_client([("fail", UNAUTHORIZED, 0.05)], 200.0)
    assert status["state"] == "refused" and status["why"] == "401 Unauthorized: check the credentials file"
    assert min(gaps(caster.starts)) >= 10.0 and status["connected"] is False


def test_dropped_at_once_is_never_retried_sooner_than_10_s():
    caster, _, status, batches = run_client([("stream", 0.5, "drop")], 300.0)
    assert min(gaps(caster.starts)) >= 10.0 and gaps(caster.starts)[:4] == [10.6, 10.6, 20.6, 40.6]  # 0.6 s of data, then the backoff
    assert batches and status["why"].startswith("caster closed the stream after 0 s of data")


def test_after_a_long_stream_a_restarted_caster_is_tried_at_once_and_streams_again():
    script = [("stream", 120.0, "drop"), ("fail", REFUSED, 0.0), ("fail", REFUSED, 0.0), ("stream", 1e9, "drop")]
    caster, client, status, _ = run_client(script, 200.0)
    g = gaps(caster.starts)
    assert g[0] == pytest.approx(120.2, abs=0.3)        # the drop, then at once
    assert g[1:3] == [10.0, 10.0]                       # the caster restarting: 20 s down
    assert status["state"] == "streaming" and client.connects == 2 and status["why"] is None


def test_after_a_caster_restart_of_a_few_seconds_corrections_flow_again_within_15_s():
    """The goal of issue 28: the drop, an attempt at once (the caster is still down), the
    next 10 s later, streaming."""
    script = [("stream", 120.0, "drop"), ("fail", REFUSED, 0.0), ("stream", 1e9, "drop")]
    caster, client, status, batches = run_client(script, 150.0)
    assert gaps(caster.starts)[1] == 10.0 and status["state"] == "streaming"
    dropped_at = caster.starts[1]                       # the attempt at once is the drop's time
    back = caster.starts[2]
    assert back - dropped_at <= 15.0 and client.connects == 2


def test_a_stream_that_goes_silent_is_closed_after_the_inactivity_timeout():
    caster, client, status, _ = run_client([("stream", 30.0, "silent")], 45.0, inactivity_s=10.0)
    assert client.errors["silences"] == 1 and len(caster.starts) == 2
    assert gaps(caster.starts)[0] == pytest.approx(40.2, abs=0.6)   # 30 s of data, 10 s of silence, at once


def test_slow_answers_count_from_the_attempts_start():
    caster, _, _, _ = run_client([("fail", SLOW, 10.0)], 300.0)
    assert min(gaps(caster.starts)) >= 20.0                 # 10 s to fail, then the backoff


def test_garbage_between_frames_is_counted_and_each_read_is_one_batch():
    _, client, status, batches = run_client([("stream", 1e9, "drop")], 5.0)
    assert all(b.types == [1005] and b.base_id == "42" for b in batches)
    assert client.errors["garbage_bytes"] == 2 * len(batches)
    assert status["base_id"] == "42" and client.messages == {1005: len(batches)}
    assert status["bytes_per_s"] == pytest.approx(len(batches) * len(frame(1005)) / 10.0, abs=5.0)


def test_gga_goes_with_the_request_then_every_interval():
    where = Position(38.7, -9.1, 100.0)
    caster = ScriptedCaster(("stream", 1e9, "drop"))
    links = []

    def opened(*args):
        link = caster.open(*args)
        links.append(link)
        return link
    with VirtualClock(watchdog_s=10.0) as vc:
        cfg = ClientConfig(CasterAddress("caster", 2101, "MP"), gga_interval_s=5.0)
        client = NtripClient(cfg, on_batch=lambda b: None, open_link=opened, position=lambda: where).start()
        vc.run_for(21.0)
        client.stop()
        vc.run_for(1.0)
    assert caster.positions == [where]
    assert len(links[0].sent) == 4 and all(s.startswith(b"$GPGGA,") for s in links[0].sent)
    assert client.gga_sent == 5


@settings(max_examples=25, deadline=None)
@given(st.lists(st.sampled_from(["refused", "401", "slow", "drop", "short", "long", "silent"]),
                min_size=3, max_size=12))
def test_whatever_the_caster_does_attempts_are_10_s_apart(behaviours):
    steps = {"refused": ("fail", REFUSED, 0.0), "401": ("fail", UNAUTHORIZED, 0.2), "slow": ("fail", SLOW, 10.0),
             "drop": ("stream", 0.0, "drop"), "short": ("stream", 5.0, "drop"),
             "long": ("stream", 30.0, "drop"), "silent": ("stream", 3.0, "silent")}
    caster, _, _, _ = run_client([steps[b] for b in behaviours] + [("fail", REFUSED, 0.0)], 600.0)
    assert min(gaps(caster.starts)) >= 10.0 - 1e-6


class StumblingPolicy(RetryPolicy):
    """The policy with a bug: its second `started` raises."""

    def started(self, now: float) -> None:
        self.calls = getattr(self, "calls", 0) + 1
        if self.calls == 2:
            raise RuntimeError("a bug in the retry timing")
        super().started(now)


def test_an_attempt_that_raises_does_not_end_the_loop(caplog):
    caster = ScriptedCaster(("fail", REFUSED, 0.0))
    with VirtualClock(watchdog_s=10.0) as vc:
        client = NtripClient(ClientConfig(CasterAddress("caster", 2101, "MP")), on_batch=lambda b: None,
                             open_link=caster.open, policy=StumblingPolicy(MIN_S)).start()
        vc.run_for(15.0)
        stumbled = client.status()
        vc.run_for(100.0)
        status = client.status()
        client.stop()
        vc.run_for(2.0)
    assert stumbled["state"] == "waiting" and stumbled["why"] == "internal error: RuntimeError"
    assert client.errors["internal_errors"] == 1 and len(caster.starts) >= 4
    assert gaps(caster.starts)[:2] == [20.0, 10.0]      # the bug at 10 s, then 10 s more, then the backoff
    assert status["state"] == "waiting" and status["why"] == "connection refused"
    assert [r.levelname for r in caplog.records if "internal error" in r.getMessage()] == ["ERROR"]


# -- real connections to the caster's twin ------------------------------------------------------------
ORIGIN = (38.7369, -9.1427, 100.0)
USER, PASSWORD = "rover", "s3cr3t-Pa55:word"
#: the twin's GPS time runs 10x: ten epochs (1004, every second) a real second
FAST = 10.0


@pytest.fixture
def twin():
    casters = []

    def make(**kw):
        kw.setdefault("mountpoints", {"VIENA0": Mountpoint.at(ORIGIN, 1000.0, 45.0, station_id=2050),
                                      "VRS": Mountpoint.at(ORIGIN, 0.0, station_id=17, vrs=True)})
        kw.setdefault("users", {USER: PASSWORD})
        caster = CasterTwin(timebase=Timebase(rate=FAST), **kw).start()
        casters.append(caster)
        return caster
    yield make
    for caster in casters:
        caster.stop()


@pytest.fixture
def login(tmp_path):
    return str(write(tmp_path / "ntrip.credentials", f"{USER}:{PASSWORD}\n", 0o600))


class Running:
    """A client on real sockets, run in a thread of its own, its batches kept."""

    def __init__(self, address, credentials="", policy=None, position=None, **config):
        self.batches = []
        self.position = position
        cfg = ClientConfig(address, credentials, **config)
        self.client = NtripClient(cfg, on_batch=self.batches.append, policy=policy,
                                  position=lambda: self.position)

    def __enter__(self):
        self.client.start()
        return self

    def __exit__(self, *exc):
        self.client.stop()

    def until(self, predicate, timeout=5.0):
        assert wait_until(lambda: predicate(self.client.status()), timeout), self.client.status()
        return self.client.status()


def frames_of(data: bytes) -> list:
    """Every frame in data, parsed by pyrtcm; data holds nothing else."""
    out, i = [], 0
    while i < len(data):
        n = ((data[i + 1] & 3) << 8 | data[i + 2]) + 6
        out.append(RTCMReader.parse(data[i:i + n]))
        i += n
    return out


@pytest.mark.slow  # the caster's twin over real sockets
@pytest.mark.parametrize("version", ["1.0", "2.0"])
def test_streams_checked_rtcm3_from_the_twin(twin, login, version):
    caster = twin()
    with Running(CasterAddress("127.0.0.1", caster.port, "VIENA0", version), login) as run:
        status = run.until(lambda s: s["messages"].get("1005", 0) >= 1 and s["messages"].get("1004", 0) >= 5)
    assert status["state"] == "streaming" and status["connected"] and status["base_id"] == "2050"
    assert status["attempts"] == status["connects"] == 1 and status["why"] is None
    parsed = [m for b in run.batches for m in frames_of(b.data)]
    assert [int(m.identity) for m in parsed] == [t for b in run.batches for t in b.types]
    assert {m.DF003 for m in parsed if hasattr(m, "DF003")} == {2050}
    assert caster.clients[-1].version == version and run.client.errors["garbage_bytes"] == 0


@pytest.mark.slow  # the caster's twin over real sockets
def test_credentials_never_reach_a_log(twin, login, tmp_path, caplog):
    caplog.set_level(logging.DEBUG)
    for name in ("pygnssutils", "pyrtcm", "pynmeagps", "viena"):
        logging.getLogger(name).setLevel(logging.DEBUG)
    caster = twin()
    wrong = str(write(tmp_path / "wrong", f"{USER}:{PASSWORD}x\n", 0o600))
    try:
        for version in ("1.0", "2.0"):
            with Running(CasterAddress("127.0.0.1", caster.port, "VIENA0", version), login) as run:
                run.until(lambda s: s["messages"].get("1004", 0) >= 2)
            with Running(CasterAddress("127.0.0.1", caster.port, "VIENA0", version), wrong) as run:
                run.until(lambda s: s["state"] == "refused")
    finally:
        for name in ("pygnssutils", "pyrtcm", "pynmeagps", "viena"):
            logging.getLogger(name).setLevel(logging.NOTSET)
    text = "\n".join(f"{r.name} {r.getMessage()} {r.exc_text or ''}" for r in caplog.records)
    assert "Response Headers" in text                # pygnssutils' DEBUG lines were captured
    secrets = [PASSWORD, base64.b64encode(f"{USER}:{PASSWORD}".encode()).decode(),
               base64.b64encode(f"{USER}:{PASSWORD}x".encode()).decode(), "s3cr3t"]
    assert not [s for s in secrets if s in text]


@pytest.mark.slow  # the caster's twin over real sockets
def test_a_wrong_password_is_401_in_one_line(twin, tmp_path):
    caster = twin()
    wrong = str(write(tmp_path / "wrong", f"{USER}:guess\n", 0o600))
    with Running(CasterAddress("127.0.0.1", caster.port, "VIENA0"), wrong) as run:
        status = run.until(lambda s: s["state"] == "refused")
    assert status["why"] == "401 Unauthorized: check the credentials file"
    assert run.client.errors["unauthorized"] == 1 and status["next_attempt_s"] > 9.0


@pytest.mark.slow  # the caster's twin over real sockets
@pytest.mark.parametrize("version, answer", [("1.0", "sourcetable"), ("2.0", "404")])
def test_a_wrong_mountpoint_is_named(twin, login, version, answer):
    caster = twin()
    with Running(CasterAddress("127.0.0.1", caster.port, "VIENA9", version), login) as run:
        status = run.until(lambda s: s["state"] == "refused")
    listed = " (it lists VIENA0, VRS)" if version == "1.0" else ""
    assert status["why"] == f"mountpoint VIENA9 not in the caster's source table{listed}"
    assert caster.clients[-1].answer == answer and run.client.errors["mountpoint_unknown"] == 1


def test_a_caster_that_is_down_is_connection_refused():
    with Running(CasterAddress("127.0.0.1", free_port(), "VIENA0")) as run:
        status = run.until(lambda s: s["state"] == "waiting" and s["why"])
    assert status["why"] == "connection refused" and run.client.errors["connection_refused"] == 1


@pytest.mark.slow  # the caster's twin over real sockets
def test_a_caster_that_answers_html(twin, login):
    caster = twin()
    caster.answer_html = True
    with Running(CasterAddress("127.0.0.1", caster.port, "VIENA0"), login) as run:
        status = run.until(lambda s: s["state"] == "refused")
    assert status["why"] == "caster answered HTML, not NTRIP (text/html)"
    assert run.client.errors["html_answers"] == 1


@pytest.mark.slow  # the caster's twin over real sockets
@pytest.mark.parametrize("version", ["1.0", "2.0"])
def test_garbage_between_frames_is_counted_and_never_passed_on(twin, login, version):
    caster = twin()
    caster.garbage_every_s = 0.3
    with Running(CasterAddress("127.0.0.1", caster.port, "VIENA0", version), login) as run:
        run.until(lambda s: s["messages"].get("1004", 0) >= 10)
        caster.garbage_every_s = 0.0
        served = caster.clients[-1]
        assert wait_until(lambda: run.client.errors["garbage_bytes"] == served.garbage_bytes > 0, 3.0)
    assert [int(m.identity) for b in run.batches for m in frames_of(b.data)] == \
        [t for b in run.batches for t in b.types]


@pytest.mark.slow  # the caster's twin over real sockets
def test_raw_relays_the_bytes_as_they_come(twin, login):
    caster = twin()
    caster.garbage_every_s = 0.5
    with Running(CasterAddress("127.0.0.1", caster.port, "VIENA0", "1.0"), login, format="RAW") as run:
        status = run.until(lambda s: s["bytes_per_s"] > 0 and caster.clients[-1].garbage_bytes > 0)
        caster.silent, caster.garbage_every_s = True, 0.0
        served = caster.clients[-1]
        assert wait_until(lambda: sum(len(b.data) for b in run.batches) == served.bytes_sent - len(b"ICY 200 OK\r\n"), 3.0)
    assert status["messages"] == {} and all(b.types == [] and b.base_id is None for b in run.batches)
    assert run.client.errors["garbage_bytes"] == 0


def make_ca_and_server_cert(folder):
    """A CA and a server certificate for 127.0.0.1 it signed; (ca, cert, key) paths."""
    import datetime as dt
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    def name(cn):
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])
    now = dt.datetime.now(dt.UTC)
    ca_key, key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca = (x509.CertificateBuilder().subject_name(name("test caster CA")).issuer_name(name("test caster CA"))
          .public_key(ca_key.public_key()).serial_number(1).not_valid_before(now - dt.timedelta(hours=1))
          .not_valid_after(now + dt.timedelta(days=1))
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .sign(ca_key, hashes.SHA256()))
    cert = (x509.CertificateBuilder().subject_name(name("127.0.0.1")).issuer_name(ca.subject)
            .public_key(key.public_key()).serial_number(2).not_valid_before(now - dt.timedelta(hours=1))
            .not_valid_after(now + dt.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                           critical=False)
            .sign(ca_key, hashes.SHA256()))
    paths = folder / "ca.pem", folder / "cert.pem", folder / "key.pem"
    paths[0].write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    paths[1].write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    paths[2].write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    os.chmod(paths[2], stat.S_IRUSR | stat.S_IWUSR)
    return tuple(str(p) for p in paths)


@pytest.mark.slow  # the caster's twin over real sockets
def test_tls_with_the_casters_own_ca_and_not_without_it(twin, login, tmp_path):
    ca, cert, key = make_ca_and_server_cert(tmp_path)
    caster = twin(tls_cert=cert, tls_key=key)
    address = CasterAddress("127.0.0.1", caster.port, "VIENA0", "2.0", tls=True, ca_file=ca)
    with Running(address, login) as run:
        status = run.until(lambda s: s["messages"].get("1004", 0) >= 3)
    assert status["tls"] and status["base_id"] == "2050"
    untrusted = CasterAddress("127.0.0.1", caster.port, "VIENA0", "2.0", tls=True)
    with Running(untrusted, login) as run:
        status = run.until(lambda s: s["state"] == "refused")
    assert status["why"].startswith("TLS: the caster's certificate is not trusted (")
    assert status["why"].endswith("): check ca_file") and run.client.errors["tls_errors"] == 1


@pytest.mark.slow  # the caster's twin over real sockets
def test_a_dropped_client_connects_again_and_a_restarted_caster_streams_again(twin, login):
    caster = twin()
    quick = RetryPolicy(min_interval_s=0.5, max_interval_s=1.0)      # the rule's shape, in half seconds
    with Running(CasterAddress("127.0.0.1", caster.port, "VIENA0"), login, policy=quick) as run:
        run.until(lambda s: s["messages"].get("1004", 0) >= 3)
        caster.drop_clients()
        run.until(lambda s: s["connects"] == 2 and s["state"] == "streaming")
        caster.restart(down_s=1.5 * FAST)                               # 1.5 s of real time down
        run.until(lambda s: s["state"] == "waiting" and s["why"] == "connection refused", 3.0)
        status = run.until(lambda s: s["connects"] == 3 and s["state"] == "streaming", 6.0)
    starts = [c.connected_s for c in caster.clients]
    assert min(b - a for a, b in zip(starts, starts[1:])) >= 0.5
    assert status["attempts"] > 3 and run.client.errors["dropped"] == 2


@pytest.mark.slow  # the caster's twin over real sockets
@pytest.mark.parametrize("version", ["1.0", "2.0"])
@pytest.mark.parametrize("fix_at_start", [True, False])
def test_gga_goes_upstream_and_a_vrs_mountpoint_streams_once_it_came(twin, login, version, fix_at_start):
    """A VRS caster answers and then waits for the rover's GGA: with a fix at the start the
    GGA goes with the request; without, as soon as one comes."""
    caster = twin()
    here = Position(38.7369, -9.1427, 100.0, sats=10)
    with Running(CasterAddress("127.0.0.1", caster.port, "VRS", version), login, gga_interval_s=0.5,
                 position=here if fix_at_start else None) as run:
        if not fix_at_start:
            run.until(lambda s: s["state"] == "streaming")
            assert run.batches == []
            run.position = here
        status = run.until(lambda s: s["messages"].get("1004", 0) >= 3 and len(caster.clients[-1].gga) >= 3)
    client = caster.clients[-1]
    assert client.base is not None and abs(client.base.position[0] - 38.7369) < 1e-4
    assert len(client.gga) >= 3 and all(",3844.21400,N,00908.56200,W," in g for g in client.gga)
    assert status["base_id"] == "17" and status["attempts"] == 1


@pytest.mark.slow  # the caster's twin over real sockets
def test_an_icy_answer_with_headers_is_not_taken_for_data(twin, login):
    caster = twin(icy_headers=True)
    with Running(CasterAddress("127.0.0.1", caster.port, "VIENA0", "1.0"), login) as run:
        run.until(lambda s: s["messages"].get("1004", 0) >= 3)
    assert run.client.errors["garbage_bytes"] == 0


@pytest.mark.slow  # the caster's twin over real sockets
def test_the_source_table_of_the_twin(twin):
    caster = twin()
    table = fetch_sourcetable(CasterAddress("127.0.0.1", caster.port))
    assert [row[0] for row in table] == ["VIENA0", "VRS"]
    found = by_distance(mountpoints(table), *ORIGIN[:2])
    assert found[0][0].name == "VRS" and found[0][1] < 0.01 and 0.9 < found[1][1] < 1.1
    with pytest.raises(LinkError, match="connection refused"):
        fetch_sourcetable(CasterAddress("127.0.0.1", free_port()))
