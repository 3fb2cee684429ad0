"""The monitor on rich tables (issue 14): at 120 columns no panel cuts its key fields short;
errors are red while they happen, not for a lifetime; the words of trouble (NO FIX,
tripped, fault) are red and stale values yellow; and a router that cannot be reached is a
screen saying so. Rendered with a test clock into a console that records styles."""
from __future__ import annotations

import io
import re

import pytest
from rich.console import Console
from vienatest import free_port, viena

from viena.monitor import MonitorModel, render, render_unreachable

STEERING = {"t": 1, "seq": 9, "phase": "tracking", "armed": True, "owner": "alice", "angle_deg": 3.25,
            "angle_qc": 1200, "target_deg": 4.5, "target_qc": 1660, "goal_deg": 5.0, "ds402": "OPERATION_ENABLED",
            "statusword": 0x0637, "following_error_qc": 12, "drive_heartbeat": "ok", "watchdog": "tripped",
            "trip": "watchdog: no setpoint for 0.25 s", "fault": "0x8611 following error",
            "emcy": None, "calibrated": True, "limits_deg": [-29.0, 29.0]}
FIX = {"t": 1, "seq": 1, "unit": "gnss0", "valid": False, "pos_status": "INSUFFICIENT_OBS", "pos_type": "NONE",
       "sats_used": 2, "sats_tracked": 5, "ecef_sigma_m": [9.0, 9.0, 9.0], "lat_deg": 38.7, "lon_deg": -9.1,
       "height_m": 100.0, "latency_s": 0.05}


def health(errors: dict) -> dict:
    return {"t": 1, "seq": 1, "service": "gnss", "unit": "gnss0", "uptime_s": 60.0, "rates_hz": {"fix": 20.0},
            "counts": {"fix": 1200}, "errors": errors, "last_sample_age_s": 0.05, "state": {}}


def segments(renderable, width: int = 120) -> list[tuple[str, str]]:
    """(text, style) of every piece the console would draw, at `width` columns."""
    console = Console(file=io.StringIO(), width=width, color_system="truecolor", force_terminal=True)
    out = []
    for line in console.render_lines(renderable, console.options.update(width=width), pad=False):
        out += [(seg.text, str(seg.style or "")) for seg in line]
    return out


def plain(renderable, width: int = 120) -> str:
    console = Console(file=io.StringIO(), width=width, color_system=None)
    console.print(renderable)
    return console.file.getvalue()


def style_of(pieces: list[tuple[str, str]], text: str) -> str:
    styles = [style for piece, style in pieces if text in piece]
    assert styles, f"{text!r} not drawn"
    return styles[0]


def steering_model() -> MonitorModel:
    model = MonitorModel()
    model.sample("viena/elettra/steering/state", STEERING, now=10.0)
    model.sample("viena/elettra/gnss/gnss0/fix", FIX, now=10.0)
    return model


@pytest.mark.parametrize("width", [120, 80])
def test_no_key_field_is_cut_at_120_columns(width):
    shown = plain(render(steering_model().view(now=10.1), width=width), width)
    assert "…" not in shown
    assert max(len(line) for line in shown.splitlines()) <= width
    words = " ".join(shown.split())                 # narrower than 120 a long value wraps, whole
    for piece in ("phase tracking", "armed yes", "target_deg 4.500", "owner alice", "watchdog tripped",
                  "NO FIX"):
        assert piece in words, (piece, shown)
    if width >= 120:                                # each value on its line, none wrapped
        for pattern in (r"phase +tracking", r"armed +yes", r"target_deg +4\.500", r"fault +0x8611 following error"):
            assert re.search(pattern, shown), (pattern, shown)


def test_trouble_is_red_and_old_values_yellow():
    model = steering_model()
    pieces = segments(render(model.view(now=10.1), width=120))
    assert "red" in style_of(pieces, "NO FIX")
    assert "red" in style_of(pieces, "tripped")
    assert "red" in style_of(pieces, "0x8611 following error")
    assert "red" not in style_of(pieces, "tracking")
    stale = segments(render(model.view(now=14.0), width=120))
    assert "yellow" in style_of(stale, "STALE 4.00 s")


def test_errors_are_red_while_they_grow_and_quiet_after():
    model = MonitorModel()
    model.token("viena/elettra/alive/gnss/gnss0", True, now=0.0)
    for second in range(5):                                     # 2 errors a second
        model.sample("viena/elettra/gnss/gnss0/health", health({"crc": 2.0 * second}), now=float(second))
    [service] = model.view(now=4.5).services
    assert service.error_rates == {"crc": pytest.approx(2.0)}
    pieces = segments(render(model.view(now=4.5)))
    assert "red" in style_of(pieces, "crc 2.00")                 # the rate, in errors/s
    assert "red" in style_of(pieces, "crc 8")                    # and the total, while it grows

    for second in range(5, 20):                                 # then none for 15 s
        model.sample("viena/elettra/gnss/gnss0/health", health({"crc": 8.0}), now=float(second))
    [service] = model.view(now=19.5).services
    assert service.error_rates == {}
    pieces = segments(render(model.view(now=19.5)))
    assert "red" not in style_of(pieces, "crc 8")                # a lifetime total is not an alarm


def test_the_cannot_reach_screen_names_the_endpoint():
    why = "cannot reach the router at tls/192.168.4.1:7447: no answer (a wrong address, ...)"
    pieces = segments(render_unreachable("elettra", why, waited_s=12.4, timeout_s=30.0))
    assert "red" in style_of(pieces, "tls/192.168.4.1:7447")
    text = "".join(piece for piece, _ in pieces)
    assert "trying for 12 s; giving up after 30 s" in text


@pytest.mark.slow
def test_monitor_without_a_router_shows_why_then_says_it_in_one_line():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = viena("monitor", "--connect", endpoint, "--duration", "2", timeout=60)
    assert run.returncode == 1
    assert f"cannot reach the router at {endpoint}: nothing listens there" in run.stdout     # the screen
    assert run.stderr.strip().splitlines() == [f"viena monitor: cannot reach the router at {endpoint}: "
                                               f"nothing listens there (is the router up? `viena status`)"]
