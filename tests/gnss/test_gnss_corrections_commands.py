"""The corrections commands (INTERFACEMODE, DGPSTIMEOUT, PSRDIFFSOURCE, RTKSOURCE) and the
VERSION log against OEM4 vol. 2's binary tables (§2.6.28, 2.6.16, 2.6.40, 2.6.47, 3.4.94)."""
from __future__ import annotations

import struct

import pytest

from viena.services.gnss.driver.novatel import (
    COMMANDS,
    BodyError,
    Component,
    ComponentType,
    ComPort,
    DgpsTimeout,
    DgpsType,
    FrameDecoder,
    Header,
    InterfaceMode,
    InterfaceModeCommand,
    MessageId,
    PsrDiffSource,
    Responses,
    RtkSource,
    TimeStatus,
    Version,
    decode_command,
    decode_version,
    encode_log,
    source_id_error,
)

EVERY_CORRECTIONS_COMMAND = [
    InterfaceModeCommand(),
    InterfaceModeCommand(ComPort.COM2, InterfaceMode.RTCMV3, InterfaceMode.NONE, Responses.OFF),
    DgpsTimeout(22),
    PsrDiffSource(DgpsType.RTCM, "ANY"),
    PsrDiffSource(DgpsType.RTCA, "D36A"),
    RtkSource(DgpsType.RTCMV3, "2050"),
    RtkSource(DgpsType.NONE),
]


@pytest.mark.parametrize("cmd", EVERY_CORRECTIONS_COMMAND, ids=lambda c: f"{type(c).__name__}-{c.body().hex()}")
def test_corrections_commands_round_trip_through_a_frame(cmd):
    frame, = FrameDecoder().feed(cmd.frame(sequence=3))
    assert frame.header.message_id == cmd.MESSAGE_ID and not frame.header.is_response
    assert decode_command(frame.header, frame.body) == cmd
    assert COMMANDS[cmd.MESSAGE_ID] is type(cmd)


def test_message_ids_are_the_manuals():
    assert (MessageId.INTERFACEMODE, MessageId.DGPSTIMEOUT, MessageId.PSRDIFFSOURCE, MessageId.RTKSOURCE,
            MessageId.VERSION) == (3, 127, 493, 494, 37)


def test_interfacemode_is_four_enums_of_table_15_and_28():
    # INTERFACEMODE COM2 RTCMV3 NONE OFF: port H, rxtype H+4, txtype H+8, responses H+12
    body = InterfaceModeCommand(ComPort.COM2, InterfaceMode.RTCMV3, InterfaceMode.NONE, Responses.OFF).body()
    assert body == struct.pack("<4L", 2, 14, 0, 0)
    assert InterfaceModeCommand().body() == struct.pack("<4L", 6, 1, 1, 1)    # THISPORT NOVATEL NOVATEL ON


def test_table_28_modes():
    assert {m.name: int(m) for m in InterfaceMode} == {
        "NONE": 0, "NOVATEL": 1, "RTCM": 2, "RTCA": 3, "CMR": 4, "IMU": 7, "RTCMNOCR": 8, "CDGPS": 9,
        "TCOM1": 10, "TCOM2": 11, "TCOM3": 12, "TAUX": 13, "RTCMV3": 14, "NOVATELBINARY": 15}


def test_table_31_types():
    assert {t.name: int(t) for t in DgpsType} == {
        "RTCM": 0, "RTCA": 1, "CMR": 2, "OMNISTAR": 3, "CDGPS": 4, "SBAS": 5, "AUTO": 10, "NONE": 11, "RTCMV3": 13}


def test_dgpstimeout_is_one_ulong():
    assert DgpsTimeout(60).body() == struct.pack("<L", 60)


@pytest.mark.parametrize("cls", [PsrDiffSource, RtkSource])
def test_source_id_is_char5_padded_to_8(cls):
    # type Enum at H, ID Char[5] at H+4 "plus 3 bytes of padding to maintain 4 byte alignment"
    assert cls(DgpsType.RTCM, "ANY").body() == struct.pack("<L", 0) + b"ANY\0\0\0\0\0"
    assert cls(DgpsType.RTCMV3, "4095").body() == struct.pack("<L", 13) + b"4095\0\0\0\0"
    assert len(cls().body()) == 12
    with pytest.raises(BodyError, match="body is 11 bytes, expected 12"):
        cls.from_body(bytes(11))


@pytest.mark.parametrize("kind, source_id, ok", [
    (DgpsType.RTCM, "ANY", True), (DgpsType.RTCM, "1023", True), (DgpsType.RTCM, "1024", False),
    (DgpsType.RTCMV3, "4095", True), (DgpsType.RTCMV3, "4096", False), (DgpsType.RTCMV3, "x1", False),
    (DgpsType.CMR, "31", True), (DgpsType.CMR, "32", False),
    (DgpsType.RTCA, "D36A", True), (DgpsType.RTCA, "D36", False), (DgpsType.RTCA, "D-36", False),
    (DgpsType.AUTO, "whatever", True),
])
def test_source_ids_by_table_31(kind, source_id, ok):
    assert (source_id_error(kind, source_id) == "") is ok


# vol. 2 §3.4.94's two examples, as their binary bodies would carry them
RT2WA = Component(ComponentType.GPSCARD, "RT2WA", "SVA03130089", "OEM4g2-2.00-X2T", "2.200A1", "2.000",
                  "2004/Feb/10", "09:53:05")
PROPAK_LB = (
    Component(ComponentType.GPSCARD, "RT2WLBA", "SPA02090052", "OEM4-6.03-22T", "1.400D86", "1.005db",
              "2002/Apr/24", "15:17:29"),
    Component(ComponentType.DB_OMNISTARXILINX, "OmniXilinx", "0", "", "102", "", "2002/Apr/11", "10:56:48"),
    Component(ComponentType.DB_OMNISTARDSP, "OmniDSP", "0", "", "1.000S10", "", "2002/Apr/11", "10:56:46"),
    Component(ComponentType.IBOARD, "OMNISTAR", "07f20040", "6.01-102", "1.000S10", "704309", "", ""),
)


@pytest.mark.parametrize("components", [(RT2WA,), PROPAK_LB, ()], ids=["RT2WA", "ProPak-LB", "empty"])
def test_version_round_trips_through_a_frame(components):
    version = Version(components)
    header = Header(0, week=1263, milliseconds=311409177, time_status=TimeStatus.FINESTEERING)
    frame, = FrameDecoder().feed(encode_log(header, version))
    assert frame.header.message_id == MessageId.VERSION == 37
    assert frame.header.length == 4 + 108 * len(components)
    assert decode_version(frame) == version
    assert version.card == (components[0] if components else None)


def test_version_fields_sit_at_the_manuals_offsets():
    body = Version((RT2WA,)).body()
    assert struct.unpack_from("<lL", body) == (1, 1)                 # # comp, type GPSCARD
    assert body[8:13] == b"RT2WA" and body[8 + 15] == 0              # model Char[16] at H+8
    assert body[4 + 52:4 + 52 + 7] == b"2.200A1"                     # sw version at H+56
    assert body[4 + 84:4 + 84 + 11] == b"2004/Feb/10"                # comp date Char[12] at H+88
    assert body[4 + 96:] == b"09:53:05\0\0\0\0"                      # comp time Char[12] at H+100


@pytest.mark.parametrize("body", [b"", struct.pack("<l", 1), struct.pack("<l", -1), struct.pack("<l", 0) + bytes(108)])
def test_a_version_body_of_the_wrong_size_is_refused(body):
    with pytest.raises(BodyError, match="VERSION body is"):
        Version.from_body(body)
