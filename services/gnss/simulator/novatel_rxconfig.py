"""The twin's RXCONFIG log (§3.4.84): what the receiver holds, one log per setting, each
embedding its command (binary, its CRC inverted) or written by label (ASCII: so SBASCONTROL
reads ENABLE or DISABLE as the receiver understood the command).
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from viena.services.gnss.driver.novatel import enums
from viena.services.gnss.driver.novatel.ascii import ascii_line, rxconfig_text
from viena.services.gnss.driver.novatel.commands import (
    Com,
    Command,
    DgpsTimeout,
    DynamicsCommand,
    InterfaceModeCommand,
    Log,
    PsrDiffSource,
    RtkSource,
    sbas_keyword_value,
)
from viena.services.gnss.driver.novatel.framing import CRC_LENGTH, encode_frame

from .ports import FACTORY_BAUD
from .rtk import FACTORY_DGPS_TIMEOUT_S, Source

if TYPE_CHECKING:
    from .novatel_twin import NovatelTwin

OWN_PORT = enums.Port.COM1


def rxconfig_logs(twin: NovatelTwin, fmt: int, gps_ms: int) -> bytes:
    """Every setting's RXCONFIG log, counting down to 0, in binary or ASCII (`fmt`)."""
    settings = settings_of(twin)
    out = bytearray()
    for k, (command, text) in enumerate(settings):
        sequence = len(settings) - 1 - k
        if fmt == enums.MessageFormat.ASCII:
            out += ascii_line(rxconfig_text(command.name, text, sequence, **ascii_header(twin, gps_ms)))
        else:
            out += rxconfig_binary(twin, command, sequence, gps_ms)
    return bytes(out)


def settings_of(twin: NovatelTwin) -> list[tuple[Command, str]]:
    """What the receiver holds, as commands and as RXCONFIGA writes them (by label)."""
    sb = twin.sbas
    keyword = sbas_keyword_value(enums.SbasKeyword(sb.keyword), twin.sbas_enable_value)
    out = [(Com(enums.ComPort.COM1, twin.baud), f"COM1,{twin.baud},N,8,1,N,OFF,ON"),
           (DynamicsCommand(twin.dynamics), enums.Dynamics(twin.dynamics).name),
           (replace(sb, keyword=keyword),
            f"{enums.SbasKeyword(sb.keyword).name},{enums.SbasSystem(sb.system).name},{sb.prn},"
            f"{enums.SbasTestMode(sb.testmode).name}")]
    for e in twin.logs.values():
        out.append((Log(OWN_PORT, e.message, 0, 0, e.trigger, e.period_ms / 1000.0,
                        e.offset_ms / 1000.0, int(e.hold)),
                    f"COM1,{enums.MessageId(e.message).name}B,{enums.Trigger(e.trigger).name},"
                    f"{e.period_ms / 1000.0:.6f},{e.offset_ms / 1000.0:.6f},"
                    f"{'HOLD' if e.hold else 'NOHOLD'}"))
    return out + _correction_settings(twin)


def _correction_settings(twin: NovatelTwin) -> list[tuple[Command, str]]:
    """The settings for corrections that differ from the factory's (so a receiver told
    nothing of corrections lists what it listed before they were modelled)."""
    out: list[tuple[Command, str]] = []
    for p in twin.ports.values():
        if p.com != enums.ComPort.COM1 and p.baud != FACTORY_BAUD:
            out.append((Com(p.com, p.baud), f"{p.name},{p.baud},N,8,1,N,OFF,ON"))
        if (p.rxtype, p.txtype, p.responses) != (enums.InterfaceMode.NOVATEL, enums.InterfaceMode.NOVATEL, True):
            out.append((InterfaceModeCommand(p.com, p.rxtype, p.txtype, int(p.responses)),
                        f"{p.name},{p.rxtype.name},{p.txtype.name},{'ON' if p.responses else 'OFF'}"))
    if twin.dgps_timeout_s != FACTORY_DGPS_TIMEOUT_S:
        out.append((DgpsTimeout(int(twin.dgps_timeout_s)), f"{twin.dgps_timeout_s:.0f}"))
    for cls, source in ((PsrDiffSource, twin.psr_source), (RtkSource, twin.rtk_source)):
        if source != Source():
            out.append((cls(source.type, source.id), f"{enums.DgpsType(source.type).name},\"{source.id}\""))
    return out


def ascii_header(twin: NovatelTwin, gps_ms: int) -> dict:
    h = twin.output.header(enums.MessageId.RXCONFIG, gps_ms)
    return dict(port="COM1", idle_percent=h.idle_percent,
                time_status=enums.TimeStatus(h.time_status).name, week=h.week,
                seconds=h.milliseconds / 1000.0, receiver_status=h.receiver_status,
                sw_version=h.sw_version)


def rxconfig_binary(twin: NovatelTwin, command: Command, sequence: int, gps_ms: int) -> bytes:
    """Binary RXCONFIG: the embedded command's header and body, its CRC inverted."""
    inner = command.frame(port_address=OWN_PORT, sequence=sequence)
    crc = int.from_bytes(inner[-CRC_LENGTH:], "little") ^ 0xFFFFFFFF
    body = inner[:-CRC_LENGTH] + crc.to_bytes(CRC_LENGTH, "little")
    return encode_frame(twin.output.header(enums.MessageId.RXCONFIG, gps_ms, sequence=sequence), body)
