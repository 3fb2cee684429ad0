"""What each OEM4 takes (driver/novatel/corrections.py), from the models and firmware the
manuals name (vol. 2 §3.4.94 VERSION examples, AUTH/MODEL/VALIDMODELS; vol. 1 §4.4, §7.5)."""
from __future__ import annotations

import pytest

from viena.services.gnss.driver.novatel import Component, ComponentType, Version
from viena.services.gnss.driver.novatel.corrections import (
    RTCM3_DECODED,
    ability,
    ability_of_version,
    firmware_version,
    rtk_option,
)


@pytest.mark.parametrize("sw, version", [("2.200A1", (2, 200)), ("1.400D86", (1, 400)), ("2.310", (2, 310)),
                                         ("2.3", (2, 300)), ("3.000B12", (3, 0)), ("", None), ("x1.2", None)])
def test_firmware_is_read_as_the_manuals_vv_rrr(sw, version):
    assert firmware_version(sw) == version


@pytest.mark.parametrize("model, option", [
    ("RT2WA", "RT-2"), ("RT2WLBA", "RT-2"), ("RT2W", "RT-2"), ("RT2", "RT-2"), ("INSRT2W", "RT-2"),
    ("oem4rt2", "RT-2"), ("RT20", "RT-20"), ("RT20W", "RT-20"), ("3151R", ""), ("3151W", ""),
    ("L1L2W", ""), ("OEM4L1L2", ""),
])
def test_the_rtk_option_is_in_the_models_name(model, option):
    assert rtk_option(model) == (option, True)


def test_a_model_the_manuals_do_not_name_is_taken_as_without_rtk():
    assert rtk_option("GPSCARD9") == ("", False)
    rx = ability("GPSCARD9", "2.310")
    assert rx.formats == ("RTCM", "RTCA") and not rx.known_model
    assert "not one the manuals name" in rx.refusal("RTCMV3")


@pytest.mark.parametrize("model, sw, formats", [
    # the manual's VERSION example: an RT-2 on 2.200, before RTCMV3 is known to be there
    ("RT2WA", "2.200A1", ("RTCM", "RTCA", "CMR")),
    ("RT2WA", "2.300", ("RTCM", "RTCA", "CMR", "RTCMV3")),
    ("RT2WA", "2.310", ("RTCM", "RTCA", "CMR", "RTCMV3")),
    ("RT20", "2.310", ("RTCM", "RTCA", "CMR", "RTCMV3")),
    ("RT2WLBA", "1.400D86", ("RTCM", "RTCA", "CMR")),            # the ProPak-LB example
    ("3151R", "2.310", ("RTCM", "RTCA")),                         # DGPS only: no CMR, no RTCMV3
    ("L1L2W", "2.310", ("RTCM", "RTCA")),
])
def test_formats_by_model_and_firmware(model, sw, formats):
    rx = ability(model, sw)
    assert rx.formats == formats
    assert rx.rtcm3_types() == (RTCM3_DECODED if "RTCMV3" in formats else frozenset())


def test_the_refusal_says_what_the_receiver_takes_and_why_not():
    assert ability("3151R", "2.200").refusal("RTCMV3") == (
        "model 3151R firmware 2.200 takes RTCM, RTCA (RTCMV3 carries RTK, which needs the RT-20 or RT-2 option)")
    assert ability("RT2WA", "2.200A1").refusal("RTCMV3") == (
        "model RT2WA firmware 2.200 takes RTCM, RTCA, CMR (RTCMV3 needs firmware 2.300 or later)")
    assert ability("3151R", "2.200").refusal("CMR").endswith("(CMR carries RTK, which needs the RT-20 or RT-2 option)")
    assert ability("RT2WA", "2.310").refusal("RTCMV3") == ""
    assert ability("3151R", "2.310").refusal("RTCM") == ""


def test_rtcm3_decoded_is_1001_to_1006():
    assert sorted(RTCM3_DECODED) == [1001, 1002, 1003, 1004, 1005, 1006]


def test_the_ability_of_a_version_log_is_its_gpscards():
    version = Version((
        Component(ComponentType.DB_OMNISTARDSP, "OmniDSP", "0", "", "1.000S10"),
        Component(ComponentType.GPSCARD, "RT2WA", "SVA03130089", "OEM4g2-2.00-X2T", "2.200A1", "2.000"),
    ))
    rx = ability_of_version(version)
    assert (rx.model, rx.firmware, rx.rtk, rx.sbas) == ("RT2WA", "2.200A1", "RT-2", True)
    assert rx.summary() == "RT2WA 2.200A1: RT-2; takes RTCM, RTCA, CMR"
    assert ability_of_version(Version(())) is None
