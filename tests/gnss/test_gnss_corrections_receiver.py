"""The driver configures a receiver for corrections and writes them (receiver.py): VERSION
asked once, a format the model and firmware cannot take refused in words, the commands in
the manual's order with INTERFACEMODE of the logs' port last, then the bytes on the line
while the logs keep coming. Against the NovAtel twin on socket:// with the corrections
commands answered by corrections_helpers.CorrectionsReceiver."""
from __future__ import annotations

import pytest
from corrections_helpers import CorrectionsReceiver, rtcm3
from gnss_helpers import still
from vienatest import wait_until

from viena.common.twin.serial_port import SerialEndpoint
from viena.services.gnss.driver.novatel import (
    ComPort,
    DgpsTimeout,
    DgpsType,
    InterfaceMode,
    InterfaceModeCommand,
    NovatelReceiver,
    PsrDiffSource,
    ResponseId,
    Responses,
    RtkSource,
    StartupConfig,
)
from viena.services.gnss.driver.novatel.enums import MessageId
from viena.services.gnss.driver.novatel.startup import CorrectionsSetup
from viena.services.gnss.simulator import NovatelTwin

pytestmark = [pytest.mark.slow, pytest.mark.timeout(60)]  # receiver and twin talk in real time

BEFORE = ["UNLOGALL", "COM", "DYNAMICS", "SBASCONTROL", "LOG BESTXYZ", "LOG VERSION"]


def served(**kw):
    twin = CorrectionsReceiver(NovatelTwin(still(), seed=5, outage_interval_s=0.0), **kw)
    return twin, SerialEndpoint(twin).start()


def startup(url, setup, **kw) -> NovatelReceiver:
    rx = NovatelReceiver(url)
    rx.startup(StartupConfig(read_config=True, ask_version=True, corrections=setup, **kw))
    return rx


def wait_for(predicate, timeout=5.0):
    return wait_until(predicate, timeout, period=0.02)


def test_rtcmv3_on_the_logs_port_is_configured_last_and_the_logs_keep_coming():
    twin, endpoint = served()
    try:
        rx = startup(endpoint.url, CorrectionsSetup("RTCMV3", dgps_timeout_s=45, source_id="2050"))
        with rx:
            assert (rx.ability.model, rx.ability.rtk, rx.corrections_format) == ("RT2WA", "RT-2", "RTCMV3")
            assert rx.corrections_refused == ""
            assert twin.names == [*BEFORE, "DGPSTIMEOUT", "RTKSOURCE", "PSRDIFFSOURCE", "LOG RXCONFIG",
                                  "INTERFACEMODE"]
            assert twin.commands[6:9] == [DgpsTimeout(45), RtkSource(DgpsType.RTCMV3, "2050"),
                                          PsrDiffSource(DgpsType.RTCMV3, "2050")]
            assert twin.commands[-1] == InterfaceModeCommand(ComPort.THISPORT, InterfaceMode.RTCMV3,
                                                             InterfaceMode.NOVATEL, Responses.ON)
            frames = rtcm3(1006, 21) + rtcm3(1004, 200)
            rx.write_corrections(frames)
            assert wait_for(lambda: bytes(twin.corrections) == frames)
            before = rx.stats.logs
            assert wait_for(lambda: rx.stats.logs > before + 5)           # BESTXYZ still flows
    finally:
        endpoint.stop()


def test_a_dgps_only_model_refuses_rtcmv3_in_one_line_and_stays_single_point():
    twin, endpoint = served(model="3151R", firmware="2.200")
    try:
        with startup(endpoint.url, CorrectionsSetup("RTCMV3")) as rx:
            assert rx.corrections_format == ""
            assert rx.corrections_refused == (
                "model 3151R firmware 2.200 takes RTCM, RTCA "
                "(RTCMV3 carries RTK, which needs the RT-20 or RT-2 option)")
            assert twin.names == [*BEFORE, "LOG RXCONFIG"]          # nothing of corrections sent
            assert twin.rxtype == InterfaceMode.NOVATEL
            assert wait_for(lambda: rx.stats.logs > 5)
    finally:
        endpoint.stop()


def test_a_dgps_only_model_takes_rtcm_without_rtksource():
    twin, endpoint = served(model="3151R", firmware="2.200")
    try:
        with startup(endpoint.url, CorrectionsSetup("RTCM")) as rx:
            assert rx.corrections_format == "RTCM"
            assert twin.names == [*BEFORE, "DGPSTIMEOUT", "PSRDIFFSOURCE", "LOG RXCONFIG", "INTERFACEMODE"]
            assert twin.rxtype == InterfaceMode.RTCM
    finally:
        endpoint.stop()


def test_a_second_port_is_set_through_the_first_and_the_logs_port_keeps_taking_commands():
    twin, endpoint = served()
    try:
        setup = CorrectionsSetup("RTCMV3", port=ComPort.COM2, baud=57600)
        with startup(endpoint.url, setup) as rx:
            assert rx.corrections_format == "RTCMV3"
            assert twin.names == [*BEFORE, "DGPSTIMEOUT", "RTKSOURCE", "PSRDIFFSOURCE", "COM", "INTERFACEMODE",
                                  "LOG RXCONFIG"]
            assert twin.commands[9].port == ComPort.COM2 and twin.commands[9].baud == 57600
            assert twin.modes["COM2"] == InterfaceModeCommand(ComPort.COM2, InterfaceMode.RTCMV3,
                                                              InterfaceMode.NONE, Responses.OFF)
            assert twin.rxtype == InterfaceMode.NOVATEL
            rx.dynamics()                                           # still answers
    finally:
        endpoint.stop()


def test_without_a_version_corrections_are_refused_unless_the_check_is_off():
    twin, endpoint = served(model=None)
    try:
        with startup(endpoint.url, CorrectionsSetup("RTCMV3")) as rx:
            assert rx.version is None and "REQUESTED LOG DOES NOT EXIST" in rx.version_error
            assert rx.corrections_refused.startswith("the receiver did not say its model and firmware")
            assert "corrections_check = false" in rx.corrections_refused
    finally:
        endpoint.stop()
    twin, endpoint = served(model=None)
    try:
        with startup(endpoint.url, CorrectionsSetup("RTCMV3", check=False)) as rx:
            assert rx.corrections_format == "RTCMV3" and "RTKSOURCE" in twin.names
    finally:
        endpoint.stop()


def test_a_command_the_receiver_refuses_leaves_corrections_off():
    twin, endpoint = served(refuse={MessageId.RTKSOURCE: ResponseId.MESSAGE_INVALID_FOR_MODEL})
    try:
        with startup(endpoint.url, CorrectionsSetup("RTCMV3")) as rx:
            assert rx.corrections_format == ""
            assert rx.corrections_refused == ("RTKSOURCE rejected by the receiver: "
                                              "'MESSAGE IS INVALID FOR THIS MODEL' (response 36 MESSAGE_INVALID_FOR_MODEL)")
            assert twin.rxtype == InterfaceMode.NOVATEL and "INTERFACEMODE" not in twin.names
    finally:
        endpoint.stop()


def test_a_new_connection_starts_over_on_a_port_back_to_novatel():
    """After INTERFACEMODE the port takes no commands; the next start-up's connection (the
    break) puts it back, and the whole sequence runs again."""
    twin, endpoint = served()
    try:
        rx = startup(endpoint.url, CorrectionsSetup("RTCMV3"))
        assert rx.corrections_format == "RTCMV3"
        rx.close()
        rx.startup(StartupConfig(read_config=True, ask_version=True, corrections=CorrectionsSetup("RTCMV3")))
        assert rx.corrections_format == "RTCMV3" and twin.connections == 2
        assert twin.names.count("INTERFACEMODE") == 2
        rx.close()
    finally:
        endpoint.stop()


def test_an_unanswered_interfacemode_is_taken_as_switched_but_unconfirmed():
    """Firmware may switch the port before it answers: no answer is still switched, and
    `corrections_unconfirmed` says so until a differential fix does (the service's state)."""
    twin, endpoint = served(silent=(MessageId.INTERFACEMODE,))
    try:
        with startup(endpoint.url, CorrectionsSetup("RTCMV3", last_answer_s=0.3)) as rx:
            assert rx.corrections_format == "RTCMV3" and rx.corrections_refused == ""
            assert rx.corrections_unconfirmed and twin.rxtype == InterfaceMode.RTCMV3
            rx.write_corrections(rtcm3(1004, 100))
            assert wait_for(lambda: bytes(twin.corrections) == rtcm3(1004, 100))
        twin.silent = ()
        rx.startup(StartupConfig(read_config=True, ask_version=True, corrections=CorrectionsSetup("RTCMV3")))
        assert rx.corrections_format == "RTCMV3" and not rx.corrections_unconfirmed    # answered this time
        rx.close()
    finally:
        endpoint.stop()
