"""SBAS as the receiver says it holds it (issue 12): SBASCONTROL's binary keyword is a
setting (the OEM4 2.310 manual's table reads ENABLE 0, later firmware ENABLE 1), the
start-up ends by asking for RXCONFIG in ASCII, whose SBASCONTROL names the keyword, and the
service says in its health whether that is what it asked for. The twin reads the keyword
either way and answers RXCONFIG as the manual's examples show (docs/sensors.md#sbas)."""
from __future__ import annotations

import struct
import time

import pytest
from gnss_helpers import TwinHarness, still
from vienatest import collect, wait_until

from viena.common.samples.health import HEALTH
from viena.common.twin.serial_port import SerialEndpoint
from viena.services.gnss.driver.novatel import (
    AsciiFrame,
    FrameDecoder,
    Log,
    MessageId,
    NovatelReceiver,
    SbasControl,
    SbasKeyword,
    StartupConfig,
    Trigger,
    check_sbas,
    config_entry,
    crc32,
    message_of,
    sbas_keyword_value,
)
from viena.services.gnss.driver.novatel.ascii import AsciiError, parse_ascii
from viena.services.gnss.simulator import NovatelTwin

#: vol. 2 §3.4.84, ASCII example of RXCONFIG: three of its logs, verbatim (each one line)
MANUAL_RXCONFIGA = [
    b"#RXCONFIGA,COM1,70,72.0,UNKNOWN,0,1.656,00000000,f702,1522;#ADJUST1PPSA,COM1,70,72.0,"
    b"UNKNOWN,0,1.656,00000000,f702,1522;OFF,ONCE,0*ad21fe17*7d34bfd1\r\n",
    b"#RXCONFIGA,COM1,1,72.0,UNKNOWN,0,2.708,00000000,f702,1522;#WAASECUTOFFA,COM1,1,72.0,"
    b"UNKNOWN,0,2.708,00000000,f702,1522;-5.000000000*7af1559f*e50ccace\r\n",
    b"#RXCONFIGA,COM1,0,72.0,FINESTEERING,1263,240449.214,00000000,f702,1522;#LOGA,COM1,0,72.0,"
    b"FINESTEERING,1263,240449.214,00000000,f702,1522;COM1,BESTPOSA,ONTIME,10.000000,0.000000,"
    b"NOHOLD*2bbec7e9*8daf0216\r\n",
]


# -- the manual -------------------------------------------------------------------------
def test_the_manuals_rxconfig_example_decodes_with_both_crcs():
    frames = FrameDecoder().feed(b"".join(MANUAL_RXCONFIGA))
    entries = [config_entry(message_of(f)) for f in frames]
    assert [(e.command, e.fields, e.sequence) for e in entries] == [
        ("ADJUST1PPS", ("OFF", "ONCE", "0"), 70),
        ("WAASECUTOFF", ("-5.000000000",), 1),
        ("LOG", ("COM1", "BESTPOSA", "ONTIME", "10.000000", "0.000000", "NOHOLD"), 0)]


def test_ascii_messages_are_found_between_binary_frames_and_checked():
    binary = Log(message=MessageId.BESTXYZ).frame()
    bad = bytearray(MANUAL_RXCONFIGA[1])
    bad[70] ^= 0x01                                           # one letter changed: bad CRC
    stray = b"#\xaa\x44"                                      # a '#' in binary garbage
    decoder = FrameDecoder()
    out = []
    data = binary + MANUAL_RXCONFIGA[0] + bytes(bad) + stray + binary + MANUAL_RXCONFIGA[2]
    for k in range(0, len(data), 7):                          # in pieces, as a port reads
        out += decoder.feed(data[k:k + 7])
    kinds = ["ascii" if isinstance(f, AsciiFrame) else f.header.message_id for f in out]
    assert kinds == [MessageId.LOG, "ascii", MessageId.LOG, "ascii"]
    # the bad line fails its CRC, and so does the '#' of the message embedded in it
    assert decoder.stats.crc_errors == 2 and decoder.stats.ascii_messages == 2


def test_an_embedded_message_needs_its_inverted_crc():
    text = MANUAL_RXCONFIGA[0][1:-2].decode().rsplit("*", 1)[0]      # without RXCONFIG's CRC
    inner = text.split(";", 1)[1][1:]                         # ADJUST1PPSA,...*ad21fe17
    assert parse_ascii(inner, inverted_crc=True).name == "ADJUST1PPSA"
    with pytest.raises(AsciiError, match="bad CRC"):
        parse_ascii(inner)                                    # as a command: not one


def test_the_keyword_value_is_a_setting():
    assert sbas_keyword_value(SbasKeyword.ENABLE) == 0 == SbasControl().keyword   # the table
    assert sbas_keyword_value(SbasKeyword.DISABLE) == 1
    assert sbas_keyword_value(SbasKeyword.ENABLE, enable_value=1) == 1
    assert sbas_keyword_value(SbasKeyword.DISABLE, enable_value=1) == 0
    with pytest.raises(ValueError):
        sbas_keyword_value(SbasKeyword.ENABLE, enable_value=2)


# -- the twin ---------------------------------------------------------------------------
def rxconfig(h: TwinHarness, fmt: int) -> list:
    """LOG RXCONFIG ONCE through the harness; what came back besides the response."""
    h.twin.feed(Log(message=MessageId.RXCONFIG, message_type=fmt << 5,
                    trigger=Trigger.ONCE).frame(), h.now)
    return h.decoder.feed(h.twin.poll(h.now))


@pytest.mark.parametrize("firmware_enable", [0, 1])
def test_the_twin_reads_the_keyword_as_its_firmware_and_says_so_by_name(firmware_enable):
    h = TwinHarness(NovatelTwin(still(), seed=1, outage_interval_s=0.0,
                                sbas_enable_value=firmware_enable))
    h.command(SbasControl(0))                                 # ENABLE by the manual's table
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.05))
    out = rxconfig(h, fmt=1)
    texts = [f for f in out if isinstance(f, AsciiFrame)]
    entries = {config_entry(message_of(f)).command: config_entry(message_of(f)) for f in texts}
    said = "ENABLE" if firmware_enable == 0 else "DISABLE"
    assert entries["SBASCONTROL"].fields == (said, "AUTO", "0", "NONE")
    assert entries["COM"].fields[:2] == ("COM1", "9600")
    assert entries["LOG"].fields == ("COM1", "BESTXYZB", "ONTIME", "0.050000", "0.000000", "NOHOLD")
    assert [config_entry(message_of(f)).sequence for f in texts] == [3, 2, 1, 0]
    h.run(0.2)
    assert h.logs[-1].data.pos_type.name == ("WAAS" if said == "ENABLE" else "SINGLE")


def test_binary_rxconfig_embeds_the_command_with_its_crc_inverted():
    h = TwinHarness(NovatelTwin(still(), seed=1, outage_interval_s=0.0, sbas_enable_value=1))
    h.command(SbasControl(1))                                 # ENABLE, for this firmware
    out = [f for f in rxconfig(h, fmt=0) if not isinstance(f, AsciiFrame)
           and f.header.message_id == MessageId.RXCONFIG]
    bodies = {struct.unpack_from("<H", f.body, 4)[0]: f.body for f in out}
    body = bodies[MessageId.SBASCONTROL]
    inner, crc = body[:-4], struct.unpack("<L", body[-4:])[0]
    assert crc == crc32(inner) ^ 0xFFFFFFFF
    assert SbasControl.from_body(inner[28:]).keyword == 1    # the value it holds, as sent


def test_a_polled_log_is_once_only():
    h = TwinHarness(NovatelTwin(still(), seed=1))
    response = h.command(Log(message=MessageId.RXCONFIG, message_type=0x20,
                             trigger=Trigger.ONTIME, period=1.0))
    assert not response.ok and "TRIGGER ONTIME NOT VALID" in response.text


# -- driver and twin over socket:// -------------------------------------------------------
@pytest.mark.parametrize("firmware_enable,setting,verdict", [
    (0, 0, "confirmed"), (1, 0, "mismatch"), (1, 1, "confirmed")])
def test_startup_confirms_sbas_from_the_receivers_own_words(firmware_enable, setting, verdict):
    twin = NovatelTwin(still(), seed=2, outage_interval_s=0.0, sbas_enable_value=firmware_enable)
    endpoint = SerialEndpoint(twin).start()
    config = StartupConfig(read_config=True, sbas_enable_value=setting)
    try:
        with NovatelReceiver(endpoint.url) as rx:
            rx.startup(config)
            assert wait_until(lambda: rx.sbas() is not None, 5)
            check = check_sbas(config, rx.sbas(), waited_s=0.0, wait_s=5.0)
            pos_types = {rx.read(timeout=2).data.pos_type.name for _ in range(5)}
    finally:
        endpoint.stop()
    assert check.verdict == verdict
    assert pos_types == ({"WAAS"} if verdict == "confirmed" else {"SINGLE"})
    if verdict == "mismatch":
        assert check.reported == "DISABLE AUTO 0 NONE" and "sbas_enable_value = 1" in check.why


def test_no_report_is_unconfirmed_after_the_wait():
    config = StartupConfig(read_config=True)
    assert check_sbas(config, None, waited_s=1.0, wait_s=5.0).confirmed is None
    late = check_sbas(config, None, waited_s=5.0, wait_s=5.0)
    assert late.verdict == "unconfirmed" and late.confirmed is False
    refused = check_sbas(config, None, waited_s=0.0, wait_s=5.0, request_error="INVALID MESSAGE ID")
    assert refused.verdict == "unconfirmed" and "INVALID MESSAGE ID" in refused.why


# -- the service ----------------------------------------------------------------------------
def health_until(session, car, predicate, timeout=20.0):
    end = time.monotonic() + timeout
    last = None
    while time.monotonic() < end:
        for h in collect(session, f"viena/{car}/gnss/gnss0/health", 1, timeout=2.0, decode=HEALTH.decode):
            last = h
            if predicate(h):
                return h
    return last


@pytest.mark.slow
@pytest.mark.timeout(90)
@pytest.mark.parametrize("setting,confirmed", [(None, False), ("1", True)])
def test_the_service_reports_sbas_as_the_receiver_holds_it(router, session, procs, setting, confirmed):
    """A receiver whose firmware reads ENABLE as 1: with the manual's value the service
    says SBAS is off and counts a mismatch; with the setting it is confirmed and used."""
    twin = NovatelTwin(still(), seed=4, outage_interval_s=0.0, sbas_enable_value=1)
    endpoint = SerialEndpoint(twin).start()
    car = f"sbas{confirmed:d}"
    extra = [] if setting is None else ["--sbas-enable-value", setting]
    proc = procs.python("-m", "viena.services.gnss.service", "--connect", router, "--car", car,
                        "--unit", "gnss0", "--port", endpoint.url, *extra)
    try:
        h = health_until(session, car, lambda h: h["state"].get("sbas_confirmed") is not None
                         and h["counts"].get("fixes", 0) > 5)
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        endpoint.stop()
    assert h is not None and h["state"]["sbas_confirmed"] is confirmed
    if confirmed:
        assert h["state"]["sbas"] == "ENABLE AUTO 0 NONE" and h["errors"]["sbas_mismatches"] == 0
        assert h["state"]["pos_type"] == "WAAS"
    else:
        assert h["state"]["sbas"] == "DISABLE AUTO 0 NONE" and h["errors"]["sbas_mismatches"] == 1
        assert h["state"]["pos_type"] == "SINGLE"
        assert "set sbas_enable_value = 1" in proc.stderr.read()
