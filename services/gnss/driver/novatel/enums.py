"""OEM4 enumerations, named as in the Firmware 2.310 Command and Log Reference (vol. 2).

Values a newer firmware may send that this table does not know (INS statuses 14-17,
reserved codes) decode to a member named ``UNKNOWN_<n>`` instead of raising: a log with
an unexpected status is still a log, and its status must still be reported by name.
Table numbers are that manual's (docs/README.md#sources); docs/sensors.md#commands-and-responses
and docs/sensors.md#logs-used say what the driver relies on.
"""
from __future__ import annotations

from enum import IntEnum


class OpenEnum(IntEnum):
    """An IntEnum that accepts values it has no name for."""

    @classmethod
    def _missing_(cls, value):
        if not isinstance(value, int) or isinstance(value, bool):
            return None
        member = int.__new__(cls, value)
        member._name_ = f"UNKNOWN_{value}"
        member._value_ = value
        return member

    @classmethod
    def of(cls, value: int):
        """cls(value) for an int, by one dict look-up when the value has a name: the decoders
        call this for every status of every log, and cls(value) costs ten times as much."""
        member = cls._value2member_map_.get(value)
        return cls(value) if member is None else member


class MessageId(OpenEnum):
    """Message IDs of the commands and logs this driver speaks (Tables 10 and 44)."""

    LOG = 1
    INTERFACEMODE = 3
    COM = 4
    RESET = 18
    SAVECONFIG = 19
    UNLOG = 36
    VERSION = 37
    UNLOGALL = 38
    BESTPOS = 42
    BESTVEL = 99
    DGPSTIMEOUT = 127
    RXCONFIG = 128
    BESTXYZ = 241
    DYNAMICS = 258
    PSRDIFFSOURCE = 493
    RTKSOURCE = 494
    SBASCONTROL = 652


class MessageFormat(OpenEnum):
    """Bits 5-6 of the header's message type byte."""

    BINARY = 0
    ASCII = 1
    ABBREVIATED = 2


class Port(OpenEnum):
    """Serial port identifiers of the binary header, LOG, UNLOG, UNLOGALL (Table 5)."""

    NO_PORTS = 0
    COM1_ALL = 1
    COM2_ALL = 2
    COM3_ALL = 3
    THISPORT_ALL = 6
    ALL_PORTS = 8
    XCOM1_ALL = 9
    XCOM2_ALL = 10
    USB1_ALL = 13
    USB2_ALL = 14
    USB3_ALL = 15
    AUX_ALL = 16
    COM1 = 0x20
    COM2 = 0x40
    COM3 = 0x60
    USB = 0x80
    SPECIAL = 0xA0
    THISPORT = 0xC0


class ComPort(OpenEnum):
    """Port identifiers of the COM command (Table 15): a different table from Port."""

    COM1 = 1
    COM2 = 2
    COM3 = 3
    THISPORT = 6
    ALL = 8
    XCOM1 = 9
    XCOM2 = 10
    USB1 = 13
    USB2 = 14
    USB3 = 15
    AUX = 16


class Parity(OpenEnum):
    N = 0
    E = 1
    O = 2  # noqa: E741 - the manual's name


class Handshake(OpenEnum):
    N = 0
    XON = 1
    CTS = 2


class Trigger(OpenEnum):
    """LOG command triggers (Table 29)."""

    ONNEW = 0
    ONCHANGED = 1
    ONTIME = 2
    ONNEXT = 3
    ONCE = 4
    ONMARK = 5


class Dynamics(OpenEnum):
    """User dynamics (Table 21). AIR is the factory default the manual advises keeping."""

    AIR = 0
    LAND = 1
    FOOT = 2


class SbasKeyword(OpenEnum):
    """SBASCONTROL keyword as the OEM4 2.310 manual's table numbers it (§2.6.50: ENABLE 0,
    DISABLE 1). Every other ENABLE/DISABLE of that manual, and later NovAtel firmware,
    number them the other way (DISABLE 0, ENABLE 1): what a receiver reads is a setting
    (`commands.sbas_keyword_value`), and RXCONFIG confirms it by name."""

    ENABLE = 0
    DISABLE = 1


class SbasSystem(OpenEnum):
    """SBASCONTROL system (Table 36)."""

    NONE = 0
    AUTO = 1
    ANY = 2
    WAAS = 3
    EGNOS = 4
    MSAS = 5


class SbasTestMode(OpenEnum):
    NONE = 0
    ZEROTOTWO = 1
    IGNOREZERO = 2


class InterfaceMode(OpenEnum):
    """Serial port interface modes, what a port accepts (rxtype) or generates (txtype)
    (Table 28). A port whose rxtype is not NOVATEL (or NOVATELBINARY) takes no commands; a
    break puts it back to NOVATEL NOVATEL."""

    NONE = 0
    NOVATEL = 1
    RTCM = 2            # RTCM 2.x
    RTCA = 3
    CMR = 4
    IMU = 7
    RTCMNOCR = 8        # RTCM without the CR/LF appended (input: same as RTCM)
    CDGPS = 9
    TCOM1 = 10
    TCOM2 = 11
    TCOM3 = 12
    TAUX = 13
    RTCMV3 = 14
    NOVATELBINARY = 15


class Responses(OpenEnum):
    """INTERFACEMODE's responses field (§2.6.28): whether the port answers commands."""

    OFF = 0
    ON = 1


class DgpsType(OpenEnum):
    """The correction source of PSRDIFFSOURCE and RTKSOURCE (Table 31). CMR is for
    RTKSOURCE only; OMNISTAR, CDGPS, SBAS, AUTO and NONE ignore the ID."""

    RTCM = 0
    RTCA = 1
    CMR = 2
    OMNISTAR = 3
    CDGPS = 4
    SBAS = 5
    AUTO = 10
    NONE = 11
    RTCMV3 = 13


class ComponentType(OpenEnum):
    """VERSION log component types (Table 88)."""

    UNKNOWN = 0
    GPSCARD = 1
    CONTROLLER = 2
    ENCLOSURE = 3
    IBOARD = 4
    IMUCARD = 7
    DB_HEIGHTMODEL = 0x3A7A0000
    DB_USERAPP = 0x3A7A0001
    DB_OMNISTARDSP = 0x3A7A0002
    DB_OMNISTARXILINX = 0x3A7A0004
    DB_USERAPPAUTO = 0x3A7A0005


class TimeStatus(OpenEnum):
    """Quality of the GPS time in a header (Table 7)."""

    UNKNOWN = 20
    APPROXIMATE = 60
    COARSEADJUSTING = 80
    COARSE = 100
    COARSESTEERING = 120
    FREEWHEELING = 130
    FINEADJUSTING = 140
    FINE = 160
    FINESTEERING = 180
    SATTIME = 200


class SolutionStatus(OpenEnum):
    """Solution status (Table 48)."""

    SOL_COMPUTED = 0
    INSUFFICIENT_OBS = 1
    NO_CONVERGENCE = 2
    SINGULARITY = 3
    COV_TRACE = 4
    TEST_DIST = 5
    COLD_START = 6
    V_H_LIMIT = 7
    VARIANCE = 8
    RESIDUALS = 9
    DELTA_POS = 10
    NEGATIVE_VAR = 11
    INTEGRITY_WARNING = 13
    PENDING = 18
    INVALID_FIX = 19
    UNAUTHORIZED = 20


class PositionType(OpenEnum):
    """Position or velocity type (Table 47)."""

    NONE = 0
    FIXEDPOS = 1
    FIXEDHEIGHT = 2
    DOPPLER_VELOCITY = 8
    SINGLE = 16
    PSRDIFF = 17
    WAAS = 18
    PROPAGATED = 19
    OMNISTAR = 20
    L1_FLOAT = 32
    IONOFREE_FLOAT = 33
    NARROW_FLOAT = 34
    L1_INT = 48
    WIDE_INT = 49
    NARROW_INT = 50
    RTK_DIRECT_INS = 51
    OMNISTAR_HP = 64
    OMNISTAR_XP = 65
    CDGPS = 66


class Datum(OpenEnum):
    """Datum IDs (Table 20); only the one the receiver reports by default is named."""

    WGS84 = 61


class ResponseId(OpenEnum):
    """Binary response IDs (Table 92). The receiver's own text travels with each."""

    OK = 1
    LOG_DOES_NOT_EXIST = 2
    NOT_ENOUGH_RESOURCES = 3
    PACKET_DOES_NOT_VERIFY = 4
    COMMAND_FAILED = 5
    INVALID_MESSAGE_ID = 6
    INVALID_MESSAGE_FIELD = 7
    INVALID_CHECKSUM = 8
    MESSAGE_MISSING_FIELD = 9
    ARRAY_SIZE_EXCEEDS_MAX = 10
    PARAMETER_OUT_OF_RANGE = 11
    TRIGGER_NOT_VALID = 14
    AUTHCODE_TABLE_FULL = 15
    INVALID_DATE_FORMAT = 16
    INVALID_AUTHCODE = 17
    NO_MATCHING_MODEL = 18
    NOT_VALID_AUTHCODE_FOR_MODEL = 19
    CHANNEL_INVALID = 20
    REQUESTED_RATE_INVALID = 21
    WORD_HAS_NO_MASK = 22
    CHANNELS_LOCKED = 23
    INJECTED_TIME_INVALID = 24
    COM_PORT_NOT_SUPPORTED = 25
    MESSAGE_INCORRECT = 26
    INVALID_PRN = 27
    PRN_NOT_LOCKED_OUT = 28
    PRN_LOCKOUT_LIST_FULL = 29
    PRN_ALREADY_LOCKED_OUT = 30
    MESSAGE_TIMED_OUT = 31
    UNKNOWN_COM_PORT = 33
    HEX_STRING_NOT_FORMATTED = 34
    INVALID_BAUD_RATE = 35
    MESSAGE_INVALID_FOR_MODEL = 36
    ONLY_VALID_IN_NVM_FAIL_MODE = 40
    INVALID_OFFSET = 41
    MAX_USER_MESSAGES_REACHED = 78
    PRECISE_TIME_ALREADY_KNOWN = 84


#: The receiver's text for each response (Table 92), as a twin must send it.
RESPONSE_TEXT = {
    ResponseId.OK: "OK",
    ResponseId.LOG_DOES_NOT_EXIST: "REQUESTED LOG DOES NOT EXIST",
    ResponseId.NOT_ENOUGH_RESOURCES: "NOT ENOUGH RESOURCES IN SYSTEM",
    ResponseId.PACKET_DOES_NOT_VERIFY: "DATA PACKET DOESN'T VERIFY",
    ResponseId.COMMAND_FAILED: "COMMAND FAILED ON RECEIVER",
    ResponseId.INVALID_MESSAGE_ID: "INVALID MESSAGE ID",
    ResponseId.INVALID_MESSAGE_FIELD: "INVALID MESSAGE. FIELD = {}",
    ResponseId.INVALID_CHECKSUM: "INVALID CHECKSUM",
    ResponseId.MESSAGE_MISSING_FIELD: "MESSAGE MISSING FIELD",
    ResponseId.ARRAY_SIZE_EXCEEDS_MAX: "ARRAY SIZE FOR FIELD {} EXCEEDS MAX",
    ResponseId.PARAMETER_OUT_OF_RANGE: "PARAMETER {} IS OUT OF RANGE",
    ResponseId.TRIGGER_NOT_VALID: "TRIGGER {} NOT VALID FOR THIS LOG",
    ResponseId.AUTHCODE_TABLE_FULL: "AUTHCODE TABLE FULL - RELOAD SOFTWARE",
    ResponseId.INVALID_DATE_FORMAT: "INVALID DATE FORMAT",
    ResponseId.INVALID_AUTHCODE: "INVALID AUTHCODE ENTERED",
    ResponseId.NO_MATCHING_MODEL: "NO MATCHING MODEL TO REMOVE",
    ResponseId.NOT_VALID_AUTHCODE_FOR_MODEL: "NOT VALID AUTH CODE FOR THAT MODEL",
    ResponseId.CHANNEL_INVALID: "CHANNEL IS INVALID",
    ResponseId.REQUESTED_RATE_INVALID: "REQUESTED RATE IS INVALID",
    ResponseId.WORD_HAS_NO_MASK: "WORD HAS NO MASK FOR THIS TYPE",
    ResponseId.CHANNELS_LOCKED: "CHANNELS LOCKED DUE TO ERROR",
    ResponseId.INJECTED_TIME_INVALID: "INJECTED TIME INVALID",
    ResponseId.COM_PORT_NOT_SUPPORTED: "COM PORT NOT SUPPORTED",
    ResponseId.MESSAGE_INCORRECT: "MESSAGE IS INCORRECT",
    ResponseId.INVALID_PRN: "INVALID PRN",
    ResponseId.PRN_NOT_LOCKED_OUT: "PRN NOT LOCKED OUT",
    ResponseId.PRN_LOCKOUT_LIST_FULL: "PRN LOCKOUT LIST IS FULL",
    ResponseId.PRN_ALREADY_LOCKED_OUT: "PRN ALREADY LOCKED OUT",
    ResponseId.MESSAGE_TIMED_OUT: "MESSAGE TIMED OUT",
    ResponseId.UNKNOWN_COM_PORT: "UNKNOWN COM PORT REQUESTED",
    ResponseId.HEX_STRING_NOT_FORMATTED: "HEX STRING NOT FORMATTED CORRECTLY",
    ResponseId.INVALID_BAUD_RATE: "INVALID BAUD RATE",
    ResponseId.MESSAGE_INVALID_FOR_MODEL: "MESSAGE IS INVALID FOR THIS MODEL",
    ResponseId.ONLY_VALID_IN_NVM_FAIL_MODE: "COMMAND ONLY VALID IF IN NVM FAIL MODE",
    ResponseId.INVALID_OFFSET: "INVALID OFFSET",
    ResponseId.MAX_USER_MESSAGES_REACHED: "MAXIMUM NUMBER OF USER MESSAGES REACHED",
    ResponseId.PRECISE_TIME_ALREADY_KNOWN: "GPS PRECISE TIME IS ALREADY KNOWN",
}

#: Bauds the COM command accepts (COM command, field 3).
COM_BAUDS = (300, 600, 900, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400,
             460800, 921600)
