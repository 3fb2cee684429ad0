"""Seeing the corrections (issue 28): the monitor's GNSS panel shows each receiver's solution
type, kind and correction age (red once stale), the NTRIP client's panel the link (red while
not streaming or stale) and the corrections on the bus; `viena hz` and `viena info` say the
mix of solution types with the differential age, and the corrections' bytes a second and
RTCM message types. The arithmetic on made-up samples; `viena info` on a recording and
`viena hz` against a router, with samples published through their schemas."""
from __future__ import annotations

import io
import json
import re
import threading

import pytest
from rich.console import Console
from vienatest import open_session, viena

from viena.common.display import CORRECTIONS_STALE_S
from viena.common.recording import RecordingWriter
from viena.common.samples.corrections import CORRECTIONS, corrections_sample
from viena.common.samples.fix import FIX
from viena.common.samples.ntrip import STATE
from viena.hz import CorrectionsMix, SolutionMix
from viena.monitor import MonitorModel, render

T0 = 1_777_630_323_000_000_000
FIX_KEY = "viena/elettra/gnss/gnss0/fix"
CORRECTIONS_KEY = "viena/elettra/gnss/corrections"


def fix(pos_type: str = "NARROW_INT", diff_age_s: float | None = 1.2, base_id: str | None = "42",
        seq: int = 1, **change) -> dict:
    sample = {"t": T0 + seq * 50_000_000, "seq": seq, "unit": "gnss0", "protocol": "novatel",
              "valid": pos_type != "NONE", "pos_status": "SOL_COMPUTED" if pos_type != "NONE" else "INSUFFICIENT_OBS",
              "pos_type": pos_type, "vel_status": "SOL_COMPUTED", "vel_type": "DOPPLER_VELOCITY",
              "ecef_m": [4918528.0, -791210.0, 3969759.0], "ecef_sigma_m": [0.01, 0.012, 0.02],
              "lat_deg": 38.7369, "lon_deg": -9.1395, "height_m": 100.0, "sats_tracked": 14, "sats_used": 12,
              "gps_week": 2400, "gps_ms": 1, "t_host": T0, "latency_s": 0.05, "vel_latency_s": 0.0,
              "diff_age_s": diff_age_s, "sol_age_s": 0.0, "base_id": base_id}
    sample.update(change)
    return FIX.validate(sample)


def ntrip_state(**change) -> dict:
    sample = {"t": T0, "seq": 3, "caster": "127.0.0.1:2101", "mountpoint": "VIENA0", "version": "2.0",
              "tls": False, "format": "RTCMV3", "connected": True, "state": "streaming", "why": None,
              "next_attempt_s": None, "bytes_per_s": 1100.0, "messages": {"1005": 3, "1077": 30},
              "base_id": "42", "last_message_age_s": 0.3, "attempts": 1, "connects": 1, "gga_sent": 0}
    sample.update(change)
    return STATE.validate(sample)


def corrections(seq: int, t_ns: int, size: int = 300, types=(1077, 1087), base_id: str | None = "42") -> dict:
    return CORRECTIONS.validate(corrections_sample(t_ns, seq, "127.0.0.1:2101/VIENA0", b"\xd3" * size, "RTCMV3",
                                                  types, base_id))


def segments(renderable, width: int = 160) -> list[tuple[str, str]]:
    console = Console(file=io.StringIO(), width=width, color_system="truecolor", force_terminal=True)
    return [(seg.text, str(seg.style or "")) for line in
            console.render_lines(renderable, console.options.update(width=width), pad=False) for seg in line]


def plain(renderable, width: int = 160) -> str:
    console = Console(file=io.StringIO(), width=width, color_system=None)
    console.print(renderable)
    return console.file.getvalue()


def style_of(pieces, text: str) -> str:
    styles = [style for piece, style in pieces if text in piece]
    assert styles, f"{text!r} not drawn"
    return styles[0]


# -- the monitor ------------------------------------------------------------------------------
def rtk_model(**state_change) -> MonitorModel:
    model = MonitorModel()
    model.sample(FIX_KEY, fix(), now=10.0)
    model.sample("viena/elettra/gnss/gnss1/fix", fix("PSRDIFF", diff_age_s=CORRECTIONS_STALE_S + 15, unit="gnss1"),
                 now=10.0)
    model.sample("viena/elettra/ntrip/state", ntrip_state(**state_change), now=10.0)
    model.sample(CORRECTIONS_KEY, corrections(9, T0), now=10.0)
    return model


def test_the_gnss_panel_shows_each_solution_its_corrections_age_and_base():
    view = rtk_model().view(now=10.1)
    assert set(view.gnss) == {"gnss0", "gnss1"} and view.ntrip is not None and view.corrections is not None
    assert not any(a.key == CORRECTIONS_KEY for a in view.others)        # a panel of its own
    shown = plain(render(view, width=160))
    gnss = shown[shown.index("GNSS"):shown.index("NTRIP client")]
    row0 = next(line for line in gnss.splitlines() if line.startswith("gnss0"))
    assert "NARROW_INT" in row0 and re.search(r"\bfixed\b", row0) and "1.2 s, base 42" in row0
    pieces = segments(render(view, width=160))
    assert "red" not in style_of(pieces, "1.2 s, base 42")
    assert "red" in style_of(pieces, f"{CORRECTIONS_STALE_S + 15:.1f} s, base 42 STALE")     # gnss1's: stale


def test_the_ntrip_panel_is_quiet_while_streaming_and_red_when_not_or_stale():
    view = rtk_model().view(now=10.1)
    shown = plain(render(view, width=160))
    panel = shown[shown.index("NTRIP client"):]
    assert "127.0.0.1:2101/VIENA0" in panel and "streaming" in panel and "1100 B/s" in panel
    assert "last message" in panel and "0.30 s" in panel
    assert "RTCMV3" in panel and "1077,1087" in panel                   # the corrections' own row
    pieces = segments(render(view, width=160))
    assert "red" not in style_of(pieces, "streaming")

    down = rtk_model(state="waiting", connected=False, why="connection refused", next_attempt_s=8.0,
                     last_message_age_s=42.0).view(now=10.1)
    pieces = segments(render(down, width=160))
    assert "red" in style_of(pieces, "waiting (connection refused)")
    assert "red" in style_of(pieces, "42 s STALE")


# -- hz and info: the arithmetic --------------------------------------------------------------
def test_the_solution_mix_says_the_types_their_kinds_and_the_diff_age():
    mix = SolutionMix(window=25)
    for i in range(5):                                  # pushed out of the window
        mix.add(fix("SINGLE", diff_age_s=0.0, base_id=None, seq=i))
    for i in range(23):
        mix.add(fix("NARROW_INT", diff_age_s=1.0 + (i % 3) * 0.5, seq=10 + i))
    mix.add(fix("NARROW_FLOAT", diff_age_s=1.9, seq=40))
    mix.add(fix("NARROW_FLOAT", diff_age_s=1.0, seq=41))
    assert len(mix) == 25
    assert mix.line() == ("NARROW_INT 92 %, NARROW_FLOAT 8 % (fixed 92 %, float 8 %); "
                          "diff age p50 1.5 s, max 2.0 s; base 42")
    summary = mix.summary()
    assert summary["pos_types"] == {"NARROW_INT": 0.92, "NARROW_FLOAT": 0.08}
    assert summary["diff_age_s"] == {"p50": 1.5, "max": 2.0} and summary["base_ids"] == ["42"]

    alone = SolutionMix()
    for i in range(3):
        alone.add(fix("SINGLE", diff_age_s=0.0, base_id=None, seq=i))
    alone.add({"t": T0, "seq": 9})                     # a source without pos_type: single, as read_fix reads it
    assert alone.line() == "SINGLE 100 %; no corrections in use"
    assert SolutionMix().line() == "no fixes"


def test_the_corrections_mix_says_bytes_a_second_types_and_base():
    mix = CorrectionsMix(window=10)
    for i in range(11):                                 # one a second, 300 bytes each
        mix.add(corrections(i, T0 + i * 1_000_000_000, types=(1077, 1087) if i else (1005, 1077, 1087, 1230)))
    assert mix.summary()["data_bytes_per_s"] == pytest.approx(300.0)
    assert mix.line() == "RTCMV3 300 B/s of corrections, types 1077 x10, 1087 x10; base 42"
    one = CorrectionsMix()
    one.add(corrections(0, T0, types=(1005, 1077)))
    assert one.line() == "RTCMV3 300 B of corrections, types 1005 x1, 1077 x1; base 42"


def test_info_says_what_the_fixes_and_corrections_of_a_recording_carried(tmp_path):
    path = tmp_path / "rtk.mcap"
    writer = RecordingWriter(path, metadata={"car": "elettra"})
    for i in range(200):                                # 10 s of fixes: float for 2 s, then fixed
        pos_type = "NARROW_FLOAT" if i < 40 else "NARROW_INT"
        writer.write(FIX_KEY, FIX.encoding, T0 + i * 50_000_000, FIX.encode(fix(pos_type, diff_age_s=1.0, seq=i)))
        if i % 20 == 0:
            writer.write(CORRECTIONS_KEY, CORRECTIONS.encoding, T0 + i * 50_000_000,
                         CORRECTIONS.encode(corrections(i, T0 + i * 50_000_000, size=1000)))
    writer.close()
    run = viena("info", path)
    assert run.returncode == 0, run.stderr
    content = run.stdout[run.stdout.index("CONTENT"):]
    assert re.search(rf"{FIX_KEY} +NARROW_INT 80 %, NARROW_FLOAT 20 % \(fixed 80 %, float 20 %\); "
                     r"diff age p50 1\.0 s, max 1\.0 s; base 42", content), content
    assert re.search(rf"{CORRECTIONS_KEY} +RTCMV3 1\.0 kB/s of corrections, types 1077 x10, 1087 x10; base 42",
                     content), content
    keys = json.loads(viena("info", path, "--json").stdout)["keys"]
    assert keys[FIX_KEY]["content"]["kinds"] == {"fixed": 0.8, "float": 0.2}
    assert keys[CORRECTIONS_KEY]["content"]["types"] == {"1077": 10, "1087": 10}


# -- hz, live ---------------------------------------------------------------------------------
@pytest.mark.slow                                       # a router, a publisher and `viena hz` for 3 s
def test_hz_says_the_solution_mix_of_a_fix_key_and_the_corrections(router):
    stop = threading.Event()
    with open_session(router) as session:
        def publish() -> None:
            i = 0
            while not stop.wait(0.05):
                i += 1
                pos_type = "NARROW_INT" if i % 4 else "NARROW_FLOAT"
                session.put(FIX_KEY, FIX.encode(fix(pos_type, diff_age_s=0.5, seq=i)), encoding=FIX.encoding)
                if i % 10 == 0:
                    session.put(CORRECTIONS_KEY, CORRECTIONS.encode(corrections(i, T0 + i * 50_000_000, size=500)),
                                encoding=CORRECTIONS.encoding)
        thread = threading.Thread(target=publish, daemon=True)
        thread.start()
        try:
            hz = viena("hz", "viena/elettra/gnss/**", "--connect", router, "--duration", "3", timeout=60)
        finally:
            stop.set()
            thread.join()
    assert hz.returncode == 0, hz.stderr
    lines = hz.stdout.strip().splitlines()
    fixes = [line for line in lines if line.startswith(f"{FIX_KEY}: ")][-1]
    assert re.search(r"; NARROW_INT \d+ %, NARROW_FLOAT \d+ % \(fixed \d+ %, float \d+ %\); "
                     r"diff age p50 0\.5 s, max 0\.5 s; base 42$", fixes), fixes
    assert " Hz, period " in fixes                       # the rate line as before
    said = [line for line in lines if line.startswith(f"{CORRECTIONS_KEY}: ")][-1]
    assert re.search(r"; RTCMV3 1\.0 kB/s of corrections, types 1077 x\d+, 1087 x\d+; base 42$", said), said
