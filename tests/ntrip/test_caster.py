"""The NTRIP caster twin answers as real casters do and fails as they fail, and pyrtcm parses
every byte of RTCM it sends (services/ntrip/simulator/caster.py, protocol.py, __main__.py).

The caster's timebase runs 20 times faster than real time here, so a second of a stream
is 50 ms; its faults are flipped live, as a test of the client would."""
from __future__ import annotations

import base64
import datetime as dt
import io
import os
import socket
import ssl
import threading
import time

import pymap3d
import pytest
from pyrtcm import RTCMReader
from vienatest import wait_for_line, wait_until

from viena.services.ntrip.simulator import CasterTwin, Mountpoint, Timebase, schedule
from viena.services.ntrip.simulator.__main__ import build_parser, settings_of
from viena.services.ntrip.simulator.credentials import CredentialsError, credentials_for_caster
from viena.services.sim.model.truth import IST_ORIGIN

USER, PASSWORD = "rover", "s3cret:with:colons"
RATE = 20.0


def gga_line(lat: float, lon: float, alt: float, quality: int = 1) -> str:
    """A GGA sentence with its checksum, as a rover sends it upstream."""
    ns, ew = ("N" if lat >= 0 else "S"), ("E" if lon >= 0 else "W")
    lat, lon = abs(lat), abs(lon)
    body = (f"GPGGA,120000.00,{int(lat):02d}{(lat % 1) * 60:08.5f},{ns},{int(lon):03d}{(lon % 1) * 60:08.5f},{ew},"
            f"{quality},08,0.9,{alt:.3f},M,50.000,M,,")
    checksum = 0
    for ch in body:
        checksum ^= ord(ch)
    return f"${body}*{checksum:02X}"


def _caster(rate: float):
    mountpoints = {
        "VIENA0": Mountpoint.at(IST_ORIGIN, 2000.0, 45.0, station_id=101, seed=1),
        "MSM": Mountpoint.at(IST_ORIGIN, 8000.0, 200.0, station_id=102, seed=2, messages="msm"),
        "VRS": Mountpoint.at(IST_ORIGIN, 30_000.0, 90.0, station_id=103, seed=3, vrs=True),
    }
    c = CasterTwin(mountpoints=mountpoints, users={USER: PASSWORD}, timebase=Timebase(rate=rate)).start()
    yield c
    c.stop()


@pytest.fixture
def caster():
    yield from _caster(RATE)


class Conn:
    """A bare NTRIP client on a socket: the request as written, the answer as received."""

    def __init__(self, port: int, path: str, v2: bool = True, auth=(USER, PASSWORD), headers=(), after=b"",
                 tls: ssl.SSLContext | None = None):
        sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.sock = tls.wrap_socket(sock, server_hostname="localhost") if tls else sock
        lines = [f"GET /{path} HTTP/1.{1 if v2 else 0}", "Host: 127.0.0.1", "User-Agent: NTRIP test/1.0"]
        if v2:
            lines.append("Ntrip-Version: Ntrip/2.0")
        if auth:
            lines.append("Authorization: Basic " + base64.b64encode(f"{auth[0]}:{auth[1]}".encode()).decode())
        lines += list(headers)
        self.sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode() + after)
        self.data = b""
        self.closed = False

    def read(self, seconds: float = 0.0, until=None) -> bytes:
        """What came, reading until `until(data)` or `seconds` pass or the caster closes."""
        end = time.monotonic() + seconds
        if self.sock.fileno() < 0:                      # closed by us: what came is all there is
            return self.data
        self.sock.settimeout(0.05)
        while not self.closed and time.monotonic() < end and not (until and until(self.data)):
            try:
                more = self.sock.recv(65536)
            except TimeoutError:
                continue
            except (ConnectionResetError, ssl.SSLError):
                more = b""
            if not more:
                self.closed = True
            self.data += more
        return self.data

    def head(self) -> tuple[str, dict[str, str], bytes]:
        """(status line, headers, what followed): v1's bare `ICY 200 OK` has no blank line."""
        icy = b"ICY 200 OK\r\n"

        def bare(d: bytes) -> bool:            # NTRIP 1.0's own form: the status line, then RTCM
            return d.startswith(icy) and d[len(icy):len(icy) + 1] == b"\xd3"
        self.read(5.0, until=lambda d: b"\r\n\r\n" in d or bare(d))
        if bare(self.data) or self.data == icy:
            return "ICY 200 OK", {}, self.data[len(icy):]
        head, _, rest = self.data.partition(b"\r\n\r\n")
        status, *lines = head.decode().split("\r\n")
        return status, {k.lower(): v.strip() for k, _, v in (line.partition(":") for line in lines)}, rest

    def body(self) -> bytes:
        status, headers, rest = self.head()
        return dechunk(rest) if headers.get("transfer-encoding") == "chunked" else rest

    def close(self) -> None:
        self.sock.close()


def dechunk(data: bytes) -> bytes:
    out = b""
    while data:
        size_line, sep, rest = data.partition(b"\r\n")
        if not sep:
            break
        size = int(size_line, 16)
        if size == 0 or len(rest) < size + 2:
            break
        assert rest[size:size + 2] == b"\r\n"
        out, data = out + rest[:size], rest[size + 2:]
    return out


def rtcm_frames(data: bytes) -> list:
    """Every frame in `data`, parsed by pyrtcm with the CRC checked (a bad one raises)."""
    return [parsed for _, parsed in RTCMReader(io.BytesIO(data), validate=1, quitonerror=2)]


def observables_in(data: bytes) -> int:
    """How many whole 1004 frames came so far (a stream cut anywhere)."""
    reader = RTCMReader(io.BytesIO(data), quitonerror=0)
    return sum(1 for _, parsed in reader if parsed is not None and parsed.identity == "1004")


def frames_bytes(frames) -> int:
    return sum(len(f.serialize()) for f in frames)


# -- the protocol ----------------------------------------------------------------------------------
@pytest.mark.parametrize("v2", [False, True], ids=["ntrip1", "ntrip2"])
def test_a_stream_starts_with_the_station_then_one_epoch_a_second(v2):
    """The caster's time moves only when the test moves it, a second at a time, so a loaded
    machine cannot make the stream skip epochs (as it does for a late client: MAX_LAG_EPOCHS)."""
    tb = DrivenTimebase(1_400_000_000.5)
    mount = {"VIENA0": Mountpoint.at(IST_ORIGIN, 2000.0, 45.0, station_id=101, seed=1)}
    with CasterTwin(mountpoints=mount, users={USER: PASSWORD}, timebase=tb) as caster:
        conn = Conn(caster.port, "VIENA0", v2=v2)
        assert wait_until(lambda: caster.clients and caster.clients[-1].answer == "stream", 5.0)
        client, reads = caster.clients[-1], tb.reads
        assert wait_until(lambda: tb.reads >= reads + 3, 5.0)   # the stream's loop has seen its start
        for _ in range(4):
            sent = len(client.sent)
            tb.gps_s += 1.0
            assert wait_until(lambda sent=sent: len(client.sent) > sent, 5.0)
        conn.read(5.0, until=lambda d: d.count(b"\xd3\x00") >= len(client.sent))   # every frame sent
        status, headers, _ = conn.head()
        if v2:
            assert status == "HTTP/1.1 200 OK"
            assert headers["content-type"] == "gnss/data" and headers["transfer-encoding"] == "chunked"
            assert headers["ntrip-version"] == "Ntrip/2.0"
        else:
            assert status == "ICY 200 OK"
        conn.close()
        frames = rtcm_frames(conn.body())
        numbers = [int(f.identity) for f in frames]
        assert numbers[:3] == [1005, 1033, 1004]
        tows = [f.DF004 for f in frames if f.identity == "1004"]
        assert len(tows) == 4 and all(b - a == 1000 for a, b in zip(tows, tows[1:]))
        assert {f.DF003 for f in frames} == {101}
        wait_until(lambda: not caster.active(), 2)
        assert (client.answer, client.version, client.user, client.mountpoint) == (
            "stream", "2.0" if v2 else "1.0", USER, "VIENA0")
        assert [s.number for s in client.sent][:len(numbers)] == numbers


@pytest.mark.parametrize("v2", [False, True], ids=["ntrip1", "ntrip2"])
def test_the_source_table_lists_every_mountpoint_where_its_base_is(caster, v2):
    conn = Conn(caster.port, "", v2=v2, auth=None)
    conn.read(3.0)
    status, headers, body = conn.head()
    assert conn.closed
    if v2:
        assert status == "HTTP/1.1 200 OK" and headers["content-type"] == "gnss/sourcetable"
    else:
        assert status == "SOURCETABLE 200 OK"
    assert int(headers["content-length"]) == len(body)
    lines = body.decode().split("\r\n")
    assert lines[-2:] == ["ENDSOURCETABLE", ""]
    strs = {line.split(";")[1]: line.split(";") for line in lines if line.startswith("STR;")}
    assert set(strs) == {"VIENA0", "MSM", "VRS"}
    assert all(len(fields) == 19 for fields in strs.values())
    rtk, msm, vrs = strs["VIENA0"], strs["MSM"], strs["VRS"]
    assert rtk[3:7] == ["RTCM 3.1", "1004(1),1005(10),1033(30)", "2", "GPS"]
    assert msm[3:7] == ["RTCM 3.2", "1074(1),1084(1),1006(10),1033(30)", "2", "GPS+GLO"]
    assert (rtk[11], vrs[11], rtk[15]) == ("0", "1", "B")         # NMEA: the VRS wants GGA; Basic auth
    lat, lon, _ = caster.mountpoints["VIENA0"].base.position
    assert (float(rtk[9]), float(rtk[10])) == pytest.approx((lat, lon), abs=1e-4)


def test_an_unknown_mountpoint_is_a_source_table_in_ntrip1_and_404_in_ntrip2(caster):
    v1 = Conn(caster.port, "NOPE", v2=False)
    v1.read(3.0)
    assert v1.head()[0] == "SOURCETABLE 200 OK" and b"ENDSOURCETABLE" in v1.data
    v2 = Conn(caster.port, "NOPE")
    v2.read(3.0)
    assert v2.head()[0] == "HTTP/1.1 404 Not Found" and v2.closed


@pytest.mark.parametrize("v2", [False, True], ids=["ntrip1", "ntrip2"])
@pytest.mark.parametrize("auth", [(USER, "wrong"), ("nobody", PASSWORD), None], ids=["password", "user", "none"])
def test_wrong_credentials_are_401(caster, v2, auth):
    conn = Conn(caster.port, "VIENA0", v2=v2, auth=auth)
    conn.read(3.0)
    status, headers, body = conn.head()
    assert status == ("HTTP/1.1 401 Unauthorized" if v2 else "HTTP/1.0 401 Unauthorized")
    assert headers["www-authenticate"] == 'Basic realm="/VIENA0"'
    assert b"\xd3" not in body and conn.closed


def test_a_caster_speaks_the_versions_it_has():
    mount = {"M": Mountpoint.at(IST_ORIGIN)}
    with CasterTwin(mountpoints=mount, versions=("1.0",), timebase=Timebase(rate=RATE)) as old:
        conn = Conn(old.port, "M", v2=True, auth=None)           # an old caster ignores Ntrip-Version
        assert conn.head()[0] == "ICY 200 OK"
        conn.close()
    with CasterTwin(mountpoints=mount, versions=("2.0",), timebase=Timebase(rate=RATE), icy_headers=True) as new:
        conn = Conn(new.port, "M", v2=False, auth=None)
        assert conn.head()[1]["content-type"] == "gnss/data"
        conn.close()
    with CasterTwin(mountpoints=mount, timebase=Timebase(rate=RATE), icy_headers=True) as headed:
        conn = Conn(headed.port, "M", v2=False, auth=None)
        status, headers, _ = conn.head()
        assert status == "ICY 200 OK" and "server" in headers
        conn.close()


def test_what_is_no_ntrip_request_is_400(caster):
    sock = socket.create_connection(("127.0.0.1", caster.port), timeout=5)
    sock.sendall(b"HELLO THERE\r\n\r\n")
    assert sock.recv(4096).startswith(b"HTTP/1.1 400 Bad Request")
    sock.close()
    assert wait_until(lambda: caster.clients[-1].answer == "400", 2)


def test_pygnssutils_streams_from_the_twin():
    """A well-kept client library takes the twin's bytes as a real caster's."""
    import queue

    from pygnssutils import GNSSNTRIPClient

    mount = {"VIENA0": Mountpoint.at(IST_ORIGIN, 2000.0, 45.0, station_id=7)}
    for version in ("2.0", "1.0"):
        out: queue.Queue = queue.Queue()
        with CasterTwin(mountpoints=mount, users={USER: PASSWORD}, timebase=Timebase(rate=RATE)) as c:
            client = GNSSNTRIPClient(retries=0, timeout=2)
            client.run(server="127.0.0.1", port=c.port, https=0, mountpoint="VIENA0", datatype="RTCM",
                       version=version, ntripuser=USER, ntrippassword=PASSWORD, ggainterval=-1, output=out)
            try:
                assert wait_until(lambda q=out: q.qsize() >= 4, 5)
            finally:
                client.stop()
        got = [out.get()[1] for _ in range(4)]
        assert {m.identity for m in got} <= {"1004", "1005", "1033"} and got[-1].DF003 == 7


# -- the rover's GGA, and the VRS --------------------------------------------------------------------
def test_gga_is_recorded_from_the_request_and_the_stream(caster):
    line = gga_line(38.74, -9.14, 100.0)
    v1 = Conn(caster.port, "VIENA0", v2=False, after=(line + "\r\n").encode())
    v2 = Conn(caster.port, "VIENA0", headers=[f"Ntrip-GGA: {line}"])
    for conn in (v1, v2):
        conn.head()
        conn.sock.sendall((line.replace("120000", "120001") + "\r\n").encode())
    assert wait_until(lambda: all(len(c.gga) == 2 for c in caster.active()), 3)
    assert [c.gga[0] for c in caster.active()] == [line, line]
    v1.close()
    v2.close()


def test_a_vrs_mountpoint_waits_for_gga_then_serves_a_base_at_the_rover(caster):
    conn = Conn(caster.port, "VRS")
    conn.read(0.6)                                        # 12 epochs of the caster
    assert conn.head()[0] == "HTTP/1.1 200 OK" and not conn.body()
    rover = (38.75, -9.15, 120.0)
    conn.sock.sendall((gga_line(*rover) + "\r\n").encode())
    conn.read(3.0, until=lambda d: len(rtcm_frames(dechunk(d.partition(b"\r\n\r\n")[2]))) >= 3)
    frames = rtcm_frames(conn.body())
    arp = next(f for f in frames if f.identity == "1005")
    expected = pymap3d.geodetic2ecef(rover[0], rover[1], rover[2] + 50.0)      # GGA altitude + geoid separation
    assert (arp.DF025, arp.DF026, arp.DF027) == pytest.approx(expected, abs=0.01)
    assert arp.DF003 == 103
    conn.close()


# -- the faults -------------------------------------------------------------------------------------------
def test_drop_clients_closes_every_stream_now(caster):
    conns = [Conn(caster.port, "VIENA0"), Conn(caster.port, "MSM", v2=False)]
    for c in conns:
        c.head()
    assert wait_until(lambda: len(caster.active()) == 2, 2)
    assert caster.drop_clients() == 2
    for c in conns:
        c.read(2.0)
        assert c.closed
    assert wait_until(lambda: not caster.active(), 2)
    assert {c.why_closed for c in caster.clients} == {"dropped by the caster"}


def test_a_caster_that_drops_clients_after_a_while(caster):
    caster.drop_every_s = 10.0                            # half a second here
    conn = Conn(caster.port, "VIENA0")
    conn.read(5.0)
    assert conn.closed
    frames = rtcm_frames(conn.body())
    assert 7 <= sum(f.identity == "1004" for f in frames) <= 11
    assert wait_until(lambda: not caster.active(), 2)
    assert "drop_every_s" in caster.clients[-1].why_closed


def test_a_caster_that_answers_html(caster):
    caster.answer_html = True
    conn = Conn(caster.port, "VIENA0")
    conn.read(3.0)
    status, headers, body = conn.head()
    assert status == "HTTP/1.1 200 OK" and headers["content-type"].startswith("text/html")
    assert body.startswith(b"<!DOCTYPE html>") and conn.closed


def test_garbage_between_frames_leaves_every_frame_whole(caster):
    caster.garbage_every_s = 2.0
    conn = Conn(caster.port, "VIENA0", v2=False)
    conn.read(5.0, until=lambda d: observables_in(d) >= 15)
    conn.close()
    body = conn.body()
    frames = rtcm_frames(body)
    assert sum(f.identity == "1004" for f in frames) >= 15
    garbage = len(body) - frames_bytes(frames)
    assert garbage > 0 and caster.clients[-1].garbage_bytes >= garbage   # the tail may not have arrived
    for f in frames:
        body = body.replace(f.serialize(), b"", 1)
    assert len(body) == garbage and b"\xd3" not in body


class DrivenTimebase(Timebase):
    """The caster's GPS time, moved by the test alone (it stands still in between); its
    reads are counted, so the test knows when the caster has looked at it."""

    def __init__(self, gps_s: float):
        super().__init__()
        self.gps_s, self.reads = gps_s, 0

    def now(self) -> float:
        self.reads += 1
        return self.gps_s


def test_a_flood_of_valid_frames_at_the_rate_asked():
    """A base streaming far faster than 1 Hz: 2 kB/s on top of the schedule, every frame
    valid, their epochs inside the second. The caster's time moves only when the test moves
    it, a quarter second at a time, so the bytes are the rate's to within one frame."""
    tb, step, steps = DrivenTimebase(1_400_000_000.25), 0.25, 12
    with CasterTwin(mountpoints={"M": Mountpoint.at(IST_ORIGIN, 500.0)}, timebase=tb) as c:
        c.flood_bytes_per_s = 2000.0
        conn = Conn(c.port, "M", auth=None)
        assert wait_until(lambda: c.clients and c.clients[-1].answer == "stream", 5.0)
        client, reads = c.clients[-1], tb.reads
        assert wait_until(lambda: tb.reads >= reads + 3, 5.0)   # the stream's loop has seen its start
        for _ in range(steps):
            flooded = client.flood_bytes
            tb.gps_s += step
            assert wait_until(lambda flooded=flooded: client.flood_bytes > flooded, 5.0)
        conn.read(5.0, until=lambda d: len(d) >= client.bytes_sent)
        conn.close()
        frames = rtcm_frames(conn.body())
    flood = [f for f in frames if f.identity == "1004" and f.DF004 % 1000]
    size = max(len(f.serialize()) for f in flood)
    assert 2000.0 * step * steps - size < client.flood_bytes <= 2000.0 * step * steps
    assert sum(len(f.serialize()) for f in flood) <= client.flood_bytes
    # a flood's epochs fall between its last and now: one in each step may be a whole second
    assert len(flood) >= client.flood_bytes // size - steps
    tow_s = (tb.gps_s - step * steps) % (7 * 86400)
    assert all(tow_s < f.DF004 / 1000 <= tow_s + step * steps for f in flood)


def test_a_silent_caster_keeps_the_connection_and_sends_nothing(caster):
    caster.silent = True
    conn = Conn(caster.port, "VIENA0")
    conn.read(0.5)
    assert conn.head()[0] == "HTTP/1.1 200 OK" and not conn.body() and not conn.closed
    caster.silent = False
    conn.read(2.0, until=lambda d: b"\xd3" in d)
    assert rtcm_frames(conn.body())
    conn.close()


def test_a_mountpoint_switched_to_msm_sends_msm(caster):
    conn = Conn(caster.port, "VIENA0")
    conn.read(3.0, until=lambda d: d.count(b"\xd3\x00") >= 4)
    caster.mountpoints["VIENA0"].messages = dict(schedule.MSM)
    conn.read(3.0, until=lambda d: b"\xd3\x00" in d and {"1074", "1084"} <= {f.identity for f in rtcm_frames(dechunk(d.partition(b"\r\n\r\n")[2]))})
    conn.close()
    numbers = [f.identity for f in rtcm_frames(conn.body())]
    assert numbers.index("1074") > numbers.index("1004") and "1084" in numbers


def test_a_restart_refuses_connections_then_serves_on_the_same_port(caster):
    port = caster.port
    conn = Conn(port, "VIENA0")
    conn.head()
    caster.restart(down_s=20.0)                           # a second of real time
    conn.read(2.0)
    assert conn.closed and not caster.is_up
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
    assert caster.wait_up(5.0) and caster.port == port
    again = Conn(port, "VIENA0")
    again.read(3.0, until=lambda d: b"\xd3" in d)
    assert rtcm_frames(again.body())
    again.close()


# -- what is recorded ---------------------------------------------------------------------------------------
def test_every_frame_sent_is_recorded_with_its_epoch_and_send_time(caster):
    before = time.monotonic()
    conn = Conn(caster.port, "VIENA0")
    conn.read(3.0, until=lambda d: d.count(b"\xd3\x00") >= 6)
    conn.close()
    received = rtcm_frames(conn.body())
    sent = [s for s in caster.sent if s.monotonic_s >= before]
    assert [s.number for s in sent][:len(received)] == [int(f.identity) for f in received]
    for s, f in zip(sent, received):
        if f.identity == "1004":
            assert s.epoch_gps_s % 604_800 * 1000 == f.DF004
    assert all(before <= s.monotonic_s <= time.monotonic() for s in sent)


# -- TLS -------------------------------------------------------------------------------------------------
def self_signed(tmp_path):
    """A certificate for localhost and its key, in the test's own folder."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "localhost")])
    now = dt.datetime.now(dt.UTC)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost")]), critical=False)
            .sign(key, hashes.SHA256()))
    cert_path, key_path = tmp_path / "caster.pem", tmp_path / "caster.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    key_path.chmod(0o600)
    return str(cert_path), str(key_path)


def test_a_tls_caster_streams_over_tls_and_refuses_plain_tcp(tmp_path):
    cert, key = self_signed(tmp_path)
    mount = {"VIENA0": Mountpoint.at(IST_ORIGIN, 1000.0)}
    with CasterTwin(mountpoints=mount, users={USER: PASSWORD}, tls_cert=cert, tls_key=key,
                    timebase=Timebase(rate=RATE)) as c:
        ctx = ssl.create_default_context(cafile=cert)
        conn = Conn(c.port, "VIENA0", tls=ctx)
        conn.read(3.0, until=lambda d: d.count(b"\xd3\x00") >= 3)
        assert conn.head()[0] == "HTTP/1.1 200 OK" and rtcm_frames(conn.body())
        conn.close()
        plain = Conn(c.port, "VIENA0")
        plain.read(3.0)
        assert plain.closed and b"\xd3" not in plain.data
        assert wait_until(lambda: c.clients[-1].answer == "tls", 2)
        assert c.url("VIENA0") == f"ntrips://127.0.0.1:{c.port}/VIENA0"


# -- its life --------------------------------------------------------------------------------------------
def sockets_on(port: int) -> int:
    """How many of this process's open sockets have `port` at either end."""
    inodes = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    count = 0
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as rows:
            next(rows)
            for row in rows:
                fields = row.split()
                ports = {int(fields[1].rsplit(":", 1)[1], 16), int(fields[2].rsplit(":", 1)[1], 16)}
                count += port in ports and fields[9] in inodes
    return count


def test_stop_joins_every_thread_and_closes_every_socket():
    c = CasterTwin(mountpoints={"M": Mountpoint.at(IST_ORIGIN)}, timebase=Timebase(rate=RATE)).start()
    conns = [Conn(c.port, "M", auth=None) for _ in range(3)]
    for conn in conns:
        conn.head()
    c.restart(0.0)
    assert c.wait_up(5.0)
    more = Conn(c.port, "M", auth=None)
    more.head()
    # the listener, both ends of the last client, our ends of the three the restart dropped
    # (the caster's ends close as their threads see the drop)
    assert wait_until(lambda: sockets_on(c.port) == 1 + 2 + 3, 2)
    c.stop()
    for conn in [*conns, more]:
        conn.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("caster-")]
    assert sockets_on(c.port) == 0
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", c.port), timeout=1).close()


# -- the program -------------------------------------------------------------------------------------------
def test_settings_come_from_the_caster_table_then_the_sim_origin_then_the_flags(tmp_path):
    config = tmp_path / "sim.toml"
    config.write_text('[sim]\norigin = [40.0, -8.0, 50.0]\n[caster]\nport = 0\nmountpoint = "X"\n'
                      'baseline_m = 100.0\nmessages = "msm"\n')
    s = settings_of(build_parser().parse_args(["--config", str(config), "--baseline-m", "250"]))
    assert (s.port, s.mountpoint, s.messages, s.baseline_m, s.origin) == (0, "X", "msm", 250.0, (40.0, -8.0, 50.0))
    s = settings_of(build_parser().parse_args(["--origin", "38.5,-9.0,10", "--version", "1.0"]))
    assert (s.origin, s.versions, s.port) == ((38.5, -9.0, 10.0), ("1.0",), 2101)
    assert settings_of(build_parser().parse_args([])).origin == IST_ORIGIN


def test_a_missing_credentials_file_is_made_private_and_an_open_one_refused(tmp_path):
    path = tmp_path / "ntrip" / "car.credentials"
    made, new = credentials_for_caster(path, "viena")
    assert new and made.user == "viena" and len(made.password) >= 20
    assert path.stat().st_mode & 0o777 == 0o600 and path.parent.stat().st_mode & 0o777 == 0o700
    again, new = credentials_for_caster(path, "someone else")
    assert (again, new) == (made, False)
    path.chmod(0o644)
    with pytest.raises(CredentialsError, match="chmod 600"):
        credentials_for_caster(path)


def test_the_program_serves_the_login_it_made_and_never_shows_it(procs, tmp_path):
    path = tmp_path / "login"
    proc = procs.python("-m", "viena.services.ntrip.simulator", "--port", "0", "--mountpoint", "TEST",
                        "--baseline-m", "1500", "--bearing-deg", "90", "--credentials", path)
    line = wait_for_line(proc.stdout, "READY", timeout=20)
    port = int(line.split(":")[-1].split("/")[0])
    assert line.strip() == f"READY ntrip://127.0.0.1:{port}/TEST"
    user, password = path.read_text().strip().split(":", 1)
    conn = Conn(port, "TEST", auth=(user, password))
    assert conn.head()[0] == "HTTP/1.1 200 OK"
    conn.close()
    proc.terminate()
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0
    assert password not in out + err + line and base64.b64encode(f"{user}:{password}".encode()).decode() not in err
    path.chmod(0o640)
    refused = procs.python("-m", "viena.services.ntrip.simulator", "--port", "0", "--credentials", path)
    _, err = refused.communicate(timeout=20)
    assert refused.returncode == 2 and "chmod 600" in err and password not in err
