"""NovAtel OEM4 binary protocol: framing, commands, logs, and the receiver on a port (plus
the ASCII logs it is asked for: RXCONFIG)."""
from .ascii import AsciiMessage, ConfigEntry, config_entry, message_of
from .commands import (
    COMMANDS,
    BodyError,
    Com,
    Command,
    CommandError,
    CommandTimeout,
    DynamicsCommand,
    Log,
    Reset,
    Response,
    SaveConfig,
    SbasControl,
    Unlog,
    Unlogall,
    decode_command,
    sbas_keyword_value,
)
from .enums import (
    ComPort,
    Datum,
    Dynamics,
    Handshake,
    MessageFormat,
    MessageId,
    Parity,
    Port,
    PositionType,
    ResponseId,
    SbasKeyword,
    SbasSystem,
    SbasTestMode,
    SolutionStatus,
    TimeStatus,
    Trigger,
)
from .framing import AsciiFrame, Frame, FrameDecoder, Header, crc32, encode_frame
from .logs import LOGS, BestPos, BestVel, BestXyz, LogMessage, decode_log, encode_log
from .receiver import LogRequest, NovatelReceiver, ReceiverStats, StartupConfig
from .sbas import SbasCheck, check_sbas, wanted_sbas

__all__ = [name for name in dir() if not name.startswith("_")]
