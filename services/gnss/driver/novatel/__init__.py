"""NovAtel OEM4 binary protocol: framing, commands, logs, and the receiver on a port (plus
the ASCII logs it is asked for: RXCONFIG); which corrections a receiver takes and how they
are written to it."""
from .ascii import AsciiMessage, ConfigEntry, config_entry, message_of
from .commands import (
    COMMANDS,
    BodyError,
    Com,
    Command,
    CommandError,
    CommandTimeout,
    DgpsTimeout,
    DynamicsCommand,
    InterfaceModeCommand,
    Log,
    PsrDiffSource,
    Reset,
    Response,
    RtkSource,
    SaveConfig,
    SbasControl,
    Unlog,
    Unlogall,
    decode_command,
    sbas_keyword_value,
    source_id_error,
)
from .corrections import ReceiverAbility, ability, ability_of_version
from .enums import (
    ComponentType,
    ComPort,
    Datum,
    DgpsType,
    Dynamics,
    Handshake,
    InterfaceMode,
    MessageFormat,
    MessageId,
    Parity,
    Port,
    PositionType,
    ResponseId,
    Responses,
    SbasKeyword,
    SbasSystem,
    SbasTestMode,
    SolutionStatus,
    TimeStatus,
    Trigger,
)
from .feed import CorrectionsFeed
from .framing import AsciiFrame, Frame, FrameDecoder, Header, crc32, encode_frame
from .logs import (
    LOGS,
    BestPos,
    BestVel,
    BestXyz,
    Component,
    LogMessage,
    Version,
    decode_log,
    decode_version,
    encode_log,
)
from .receiver import NovatelReceiver, ReceiverStats
from .sbas import SbasCheck, check_sbas, wanted_sbas
from .startup import CorrectionsSetup, LogRequest, StartupConfig
from .writer import CorrectionsWriter, SecondPort

__all__ = [name for name in dir() if not name.startswith("_")]
