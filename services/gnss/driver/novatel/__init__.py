"""NovAtel OEM4 binary protocol: framing, commands, logs, and the receiver on a port."""
from .commands import (
    COMMANDS, BodyError, Com, Command, CommandError, CommandTimeout, DynamicsCommand, Log,
    Reset, Response, SaveConfig, SbasControl, Unlog, Unlogall, decode_command,
)
from .enums import (
    ComPort, Datum, Dynamics, Handshake, MessageId, Parity, Port, PositionType, ResponseId,
    SbasKeyword, SbasSystem, SbasTestMode, SolutionStatus, TimeStatus, Trigger,
)
from .framing import Frame, FrameDecoder, Header, crc32, encode_frame
from .logs import LOGS, BestPos, BestVel, BestXyz, LogMessage, decode_log, encode_log
from .receiver import LogRequest, NovatelReceiver, ReceiverStats, StartupConfig

__all__ = [name for name in dir() if not name.startswith("_")]
