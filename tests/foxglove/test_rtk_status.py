"""The corrections in Foxglove (issue 28): a receiver's LocationFix carries its RTK sigmas
unchanged (squared, as an ENU covariance of the right type), every fix also makes a JSON
status (`foxglove/gnss/<unit>/status`: solution type, kind, diff age, base), and the NTRIP
client's state one for the link (`foxglove/ntrip/status`); in the converter, and in an
exported MCAP file read back with the mcap library through the schemas it advertises."""
from __future__ import annotations

import json

import jsonschema
import pymap3d
import pytest
from foxglove_client import as_advertised, decoder, protobuf_decoder, read_all
from laptop_helpers import viena

from viena.common.display import CORRECTIONS_STALE_S
from viena.common.json_schema import json_schema
from viena.common.recording import RecordingWriter
from viena.common.samples.corrections import CORRECTIONS, corrections_sample
from viena.common.samples.fix import FIX
from viena.common.samples.ntrip import STATE
from viena.foxglove_messages import GNSS_STATUS, NTRIP_STATUS, Converter

T0 = 1_717_236_000_123_456_789
FIX_KEY = "viena/elettra/gnss/gnss0/fix"
STATE_KEY = "viena/elettra/ntrip/state"
CORRECTIONS_KEY = "viena/elettra/gnss/corrections"
GNSS_STATUS_TOPIC = "viena/elettra/foxglove/gnss/gnss0/status"
NTRIP_STATUS_TOPIC = "viena/elettra/foxglove/ntrip/status"


def fix(**change) -> dict:
    """A BESTPOS fix with an RTK fixed solution: centimetre sigmas along E, N, U."""
    lat, lon, h = 38.7369123456, -9.1395123456, 110.0
    sample = {"t": T0, "seq": 1, "unit": "gnss0", "protocol": "novatel", "valid": True,
              "pos_status": "SOL_COMPUTED", "pos_type": "NARROW_INT", "vel_status": "SOL_COMPUTED",
              "vel_type": "DOPPLER_VELOCITY", "ecef_m": [float(v) for v in pymap3d.geodetic2ecef(lat, lon, h)],
              "ecef_sigma_m": [0.011, 0.013, 0.016], "enu_sigma_m": [0.008, 0.0105, 0.0151],
              "vel_ecef_mps": None, "vel_sigma_mps": None, "lat_deg": lat, "lon_deg": lon, "height_m": h,
              "sats_tracked": 14, "sats_used": 12, "gps_week": 2317, "gps_ms": 1, "t_host": T0,
              "latency_s": 0.0, "vel_latency_s": 0.0, "diff_age_s": 1.4, "sol_age_s": 0.0, "base_id": "2050"}
    sample.update(change)
    return FIX.decode(FIX.encode(sample))


def ntrip_state(**change) -> dict:
    sample = {"t": T0, "seq": 3, "caster": "127.0.0.1:2101", "mountpoint": "VIENA0", "version": "2.0",
              "tls": False, "format": "RTCMV3", "connected": True, "state": "streaming", "why": None,
              "next_attempt_s": None, "bytes_per_s": 1100.0, "messages": {"1005": 3, "1077": 30, "1087": 30},
              "base_id": "2050", "last_message_age_s": 0.3, "attempts": 1, "connects": 1, "gga_sent": 0}
    sample.update(change)
    return STATE.decode(STATE.encode(sample))


def derived(key: str, schema, sample: dict) -> dict:
    converter = Converter()
    return {d.kind: d for d in converter.derived(converter.route(key, schema.encoding), sample)}


def location(out) -> object:
    schema = type(out.message).get_schema()
    return protobuf_decoder(schema.name, schema.data)(out.message.encode())


def valid_json(schema, message: dict) -> dict:
    """The message passes the JSON Schema its channel advertises, and viena's own check."""
    jsonschema.Draft202012Validator(json_schema(schema)).validate(message)
    return schema.validate(message)


def test_an_rtk_fix_is_a_location_with_its_sigmas_unchanged_and_a_status():
    out = derived(FIX_KEY, FIX, fix())
    assert set(out) == {"LocationFix", "GnssStatus"}
    loc = location(out["LocationFix"])
    assert list(loc.position_covariance) == [0.008 ** 2, 0, 0, 0, 0.0105 ** 2, 0, 0, 0, 0.0151 ** 2]     # exactly
    assert loc.position_covariance_type == 2                                   # DIAGONAL_KNOWN
    status = out["GnssStatus"]
    assert status.topic == GNSS_STATUS_TOPIC
    assert valid_json(GNSS_STATUS, status.message) == {
        "t": T0, "unit": "gnss0", "valid": True, "pos_status": "SOL_COMPUTED", "pos_type": "NARROW_INT",
        "kind": "fixed", "kind_level": 5, "diff_age_s": 1.4, "sol_age_s": 0.0, "base_id": "2050",
        "sats_used": 12, "sats_tracked": 14, "sigma_h_m": pytest.approx(0.0105), "sigma_v_m": pytest.approx(0.0151),
        "text": "NARROW_INT (fixed), diff age 1.4 s, base 2050, 12/14 sats, sigma 0.011 m"}


@pytest.mark.parametrize("change, kind, level, has_location", [
    ({"pos_type": "NARROW_FLOAT", "enu_sigma_m": [0.12, 0.15, 0.3]}, "float", 4, True),
    ({"pos_type": "PSRDIFF", "enu_sigma_m": [0.5, 0.6, 1.1]}, "dgps", 3, True),
    ({"pos_type": "SINGLE", "diff_age_s": 0.0, "base_id": None}, "single", 1, True),
    ({"pos_type": "NONE", "valid": False, "pos_status": "INSUFFICIENT_OBS"}, "none", 0, False),
])
def test_each_solution_kind_has_its_level_and_only_differential_ones_an_age(change, kind, level, has_location):
    out = derived(FIX_KEY, FIX, fix(**change))
    assert ("LocationFix" in out) is has_location
    status = valid_json(GNSS_STATUS, out["GnssStatus"].message)
    assert (status["kind"], status["kind_level"], status["valid"]) == (kind, level, has_location)
    assert ("diff_age_s" in status) is (kind not in ("none", "single"))       # a single fix's 0 says nothing
    assert ("sigma_h_m" in status) is has_location


def test_sigmas_from_nmea_dops_are_an_approximated_covariance():
    nmea = fix(protocol="nmea", pos_type="NARROW_INT", enu_sigma_m=[1.06, 1.06, 2.7])
    assert location(derived(FIX_KEY, FIX, nmea)["LocationFix"]).position_covariance_type == 1    # APPROXIMATED


def test_the_ntrip_status_says_the_link_and_how_fresh_its_corrections_are():
    out = derived(STATE_KEY, STATE, ntrip_state())
    assert set(out) == {"NtripStatus"} and out["NtripStatus"].topic == NTRIP_STATUS_TOPIC
    status = valid_json(NTRIP_STATUS, out["NtripStatus"].message)
    assert (status["state"], status["connected"], status["stale"]) == ("streaming", True, False)
    assert status["types"] == [1005, 1077, 1087] and status["frames"] == 63 and status["base_id"] == "2050"
    assert status["text"] == ("streaming 127.0.0.1:2101/VIENA0, 1100 B/s, types 1005,1077,1087, base 2050, "
                              "last message 0.3 s ago")

    old = valid_json(NTRIP_STATUS, derived(STATE_KEY, STATE, ntrip_state(
        last_message_age_s=CORRECTIONS_STALE_S + 5))["NtripStatus"].message)
    assert old["stale"] is True and old["text"].endswith("(STALE)")
    down = valid_json(NTRIP_STATUS, derived(STATE_KEY, STATE, ntrip_state(
        state="waiting", connected=False, why="connection refused", next_attempt_s=8.0, bytes_per_s=0.0,
        last_message_age_s=None))["NtripStatus"].message)
    assert down["stale"] is True and down["why"] == "connection refused" and "last_message_age_s" not in down
    assert down["text"].startswith("waiting 127.0.0.1:2101/VIENA0 (connection refused)")


def test_a_schema_with_raw_bytes_is_still_a_json_channel():
    """The corrections' `data` has no plain JSON type: its channel is schemaless JSON (the
    bytes as hex), never a failure to convert."""
    converter = Converter()
    route = converter.route(CORRECTIONS_KEY, CORRECTIONS.encoding)
    assert route.json_schema() is None and route.schema is CORRECTIONS
    sample = CORRECTIONS.decode(CORRECTIONS.encode(corrections_sample(T0, 1, "h:1/M", b"\xd3\x00", "RTCMV3", [1005])))
    assert json.loads(route.json(sample))["data"] == "d300"


@pytest.mark.slow                                           # `viena export` as a process
def test_the_export_holds_the_status_channels_that_pass_their_schemas(tmp_path):
    path = tmp_path / "rtk.mcap"
    writer = RecordingWriter(path, metadata={"car": "elettra"})
    kinds = ["SINGLE", "PSRDIFF", "NARROW_FLOAT", "NARROW_INT"]
    for i in range(40):
        t = T0 + i * 50_000_000
        writer.write(FIX_KEY, FIX.encoding, t, FIX.encode({**fix(pos_type=kinds[i // 10]), "t": t, "seq": i}))
        if i % 20 == 0:
            writer.write(STATE_KEY, STATE.encoding, t, STATE.encode({**ntrip_state(), "t": t}))
            writer.write(CORRECTIONS_KEY, CORRECTIONS.encoding, t, CORRECTIONS.encode(
                corrections_sample(t, i, "127.0.0.1:2101/VIENA0", b"\xd3" * 40, "RTCMV3", [1077])))
    writer.close()
    out = tmp_path / "rtk-fox.mcap"
    result = viena("export", path, "--format", "foxglove", "-o", out)
    assert result.returncode == 0, result.stderr
    _, messages = read_all(out)
    decoders, got = {}, {}
    for schema, channel, message in messages:
        decode = decoders.setdefault(channel.id, decoder(as_advertised(channel, schema)))
        value = decode(message.data)                            # raises if it does not pass
        got.setdefault(channel.topic, []).append((schema.name if schema else "", value))
    gnss = got[GNSS_STATUS_TOPIC]
    assert {name for name, _ in gnss} == {GNSS_STATUS.name} and len(gnss) == 40
    assert [v["kind"] for _, v in gnss][::10] == ["single", "dgps", "float", "fixed"]
    ntrip = got[NTRIP_STATUS_TOPIC]
    assert {name for name, _ in ntrip} == {NTRIP_STATUS.name} and [v["state"] for _, v in ntrip] == ["streaming"] * 2
    assert len(got[CORRECTIONS_KEY]) == 2                      # the corrections' own JSON channel
