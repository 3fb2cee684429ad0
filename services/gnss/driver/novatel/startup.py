"""The car's start-up sequence for a NovAtel OEM4 receiver (docs/sensors.md#start-up-sequence):
what it asks for (StartupConfig, its logs and its corrections) and the commands that ask it,
in their order: break, UNLOGALL, COM, DYNAMICS, SBASCONTROL, the LOGs, VERSION, the
corrections' commands, RXCONFIG, and on the logs' own port INTERFACEMODE last.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

from . import enums
from .commands import (
    Com,
    Command,
    CommandError,
    CommandTimeout,
    DgpsTimeout,
    InterfaceModeCommand,
    PsrDiffSource,
    RtkSource,
)

if TYPE_CHECKING:
    from .receiver import NovatelReceiver

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LogRequest:
    """One LOG of the start-up sequence."""

    message: enums.MessageId = enums.MessageId.BESTXYZ
    trigger: enums.Trigger = enums.Trigger.ONTIME
    period: float = 0.05
    offset: float = 0.0
    hold: bool = False


@dataclass(frozen=True)
class CorrectionsSetup:
    """How the receiver is to take differential corrections (start-up's last part)."""

    format: str = ""                # "" none; RTCMV3, RTCM, RTCA, CMR (INTERFACEMODE's names)
    port: enums.ComPort | None = None     # None: the logs' own port; else the receiver's port they go to
    baud: int = 0                   # that other port's rate, set by COM (0: leave it)
    dgps_timeout_s: int = 60        # DGPSTIMEOUT, 2-1000 s (RTK's is 60 s, fixed)
    source_id: str = "ANY"          # the base station to take them from (Table 31's IDs)
    check: bool = True              # refuse a format the VERSION's model and firmware do not take
    #: on the logs' own port, the wait for INTERFACEMODE's answer (it queues behind RXCONFIG)
    last_answer_s: float = 3.0


@dataclass(frozen=True)
class StartupConfig:
    """The car's start-up sequence; every field is a setting of the service."""

    initial_baud: int = 9600        # the receiver's factory baud, what a break restores
    baud: int = 115200
    send_break: bool | None = None  # None: when the URL can carry one (not socket://)
    unlogall_port: enums.Port = enums.Port.THISPORT_ALL
    dynamics: enums.Dynamics = enums.Dynamics.AIR
    sbas: enums.SbasKeyword | None = enums.SbasKeyword.ENABLE   # None: leave SBAS alone
    sbas_system: enums.SbasSystem = enums.SbasSystem.AUTO
    sbas_prn: int = 0
    sbas_testmode: enums.SbasTestMode = enums.SbasTestMode.NONE
    sbas_enable_value: int = 0      # what the firmware reads as ENABLE (manual: 0; later: 1)
    logs: tuple[LogRequest, ...] = (LogRequest(),)
    read_config: bool = False       # end with LOG RXCONFIGA ONCE: the settings by name
    ask_version: bool = False       # LOG VERSION ONCE after the logs: model and firmware
    version_timeout_s: float = 1.0  # how long the VERSION log may take after its LOG's answer
    corrections: CorrectionsSetup = CorrectionsSetup()


def run_startup(rx: NovatelReceiver, config: StartupConfig) -> None:
    """Open (if needed) and configure the receiver the way the car does."""
    if not rx.is_open:
        rx.open(config.initial_baud)
    else:
        rx.set_baud(config.initial_baud)
    send_break = rx.carries_break if config.send_break is None else config.send_break
    if send_break:
        rx.reset_port_by_break()
    _unlogall_at(rx, config)
    try:
        rx.com(config.baud)
    except CommandTimeout:
        # Some firmware switches before answering; the next command proves the link.
        log.info("%s: no answer to COM %d, switching anyway", rx.url, config.baud)
    rx.set_baud(config.baud)
    rx.dynamics(config.dynamics)
    if config.sbas is not None:
        rx.sbascontrol(config.sbas, config.sbas_system, config.sbas_prn,
                       config.sbas_testmode, config.sbas_enable_value)
    for req in config.logs:
        rx.log(req.message, req.trigger, req.period, req.offset, req.hold)
    rx.corrections_format, rx.corrections_refused = "", ""
    rx.corrections_unconfirmed = False
    if config.ask_version or config.corrections.format:
        rx.request_version(config.version_timeout_s)
    same_port = False
    if config.corrections.format:
        same_port = _configure_corrections(rx, config.corrections)
    if config.read_config:
        _request_config(rx)
    if same_port:
        _switch_this_port(rx, config.corrections)


def _configure_corrections(rx: NovatelReceiver, setup: CorrectionsSetup) -> bool:
    """Everything the receiver needs to take `setup.format` but the logs' port's own
    INTERFACEMODE; True when that is still to be sent (the caller sends it last). A
    format the receiver cannot take, or a command it refuses, leaves corrections off
    (`corrections_refused` says why) and the receiver as it was: single-point."""
    fmt = setup.format
    refusal = _refusal(rx, setup)
    if refusal:
        rx.corrections_refused = refusal
        return False
    kind = enums.DgpsType[fmt]
    rtk = rx.ability is None or bool(rx.ability.rtk)       # unchecked: try RTK too
    commands: list[Command] = [DgpsTimeout(setup.dgps_timeout_s)]
    if rtk:
        commands.append(RtkSource(kind, setup.source_id))
    if fmt != "CMR":                                            # CMR is RTK only (Table 31)
        commands.append(PsrDiffSource(kind, setup.source_id))
    if setup.port is not None:
        if setup.baud:
            commands.append(Com(port=setup.port, baud=setup.baud))
        commands.append(InterfaceModeCommand(setup.port, enums.InterfaceMode[fmt], enums.InterfaceMode.NONE,
                                             enums.Responses.OFF))
    for cmd in commands:
        try:
            rx.command(cmd)
        except (CommandError, CommandTimeout) as exc:
            rx.corrections_refused = str(exc)
            return False
    if setup.port is not None:
        rx.corrections_format = fmt
        return False
    return True


def _refusal(rx: NovatelReceiver, setup: CorrectionsSetup) -> str:
    if not setup.check:
        return ""
    if rx.ability is None:
        return (f"the receiver did not say its model and firmware ({rx.version_error or 'no VERSION'}); "
                f"corrections_check = false writes them anyway")
    return rx.ability.refusal(setup.format)


def _switch_this_port(rx: NovatelReceiver, setup: CorrectionsSetup) -> None:
    """INTERFACEMODE THISPORT <format> NOVATEL ON: the logs keep coming, the port takes
    only corrections from now on. Its answer queues behind RXCONFIG's kilobytes, and a
    receiver that switches before answering is switched all the same: without an answer
    the port is taken as switched, `corrections_unconfirmed` (until a differential fix
    says the receiver uses them)."""
    cmd = InterfaceModeCommand(enums.ComPort.THISPORT, enums.InterfaceMode[setup.format], enums.InterfaceMode.NOVATEL,
                               enums.Responses.ON)
    try:
        rx.command(cmd, timeout=max(rx.command_timeout, setup.last_answer_s))
    except CommandTimeout:
        log.info("%s: no answer to INTERFACEMODE %s, taken as switched (unconfirmed)", rx.url, setup.format)
        rx.corrections_unconfirmed = True
    except CommandError as exc:
        rx.corrections_refused = str(exc)
        return
    rx.corrections_format = setup.format


def _request_config(rx: NovatelReceiver) -> None:
    """LOG RXCONFIGA ONCE: the receiver's settings arrive as ASCII logs (into `config`).
    Last, so that its few kilobytes delay no command's response; a receiver that
    refuses it is still a working receiver, so that is only noted."""
    try:
        rx.log(enums.MessageId.RXCONFIG, enums.Trigger.ONCE, fmt=enums.MessageFormat.ASCII)
    except (CommandError, CommandTimeout) as exc:
        rx.config_request_error = str(exc)
        log.warning("%s: cannot read the receiver's configuration: %s", rx.url, exc)


def _unlogall_at(rx: NovatelReceiver, config: StartupConfig) -> None:
    """UNLOGALL at the factory rate; a receiver whose saved configuration kept the
    working rate answers at that one instead."""
    try:
        rx.unlogall(config.unlogall_port)
    except CommandTimeout:
        if config.baud == config.initial_baud:
            raise
        log.info("%s: no answer at %d baud, trying %d", rx.url, config.initial_baud,
                 config.baud)
        rx.set_baud(config.baud)
        rx.unlogall(config.unlogall_port)
