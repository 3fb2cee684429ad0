"""Every client tool fails in one line, never a traceback nor a hang (issue 14): a router
that is not there (after --timeout, connecting included, naming the endpoint), a
malformed endpoint, a malformed key expression; and says so when nothing matches."""
from __future__ import annotations

import subprocess

import pytest
from vienatest import PYTHON, VIENA, free_port, viena

pytestmark = pytest.mark.slow  # one process per case

STEER = [PYTHON, "-m", "viena.services.steering.client", "--angle-deg", "1"]
#: each client tool with what it needs besides the connection flags
TOOLS = {
    "sub": [*VIENA, "sub", "viena/elettra/**"],
    "record": [*VIENA, "record", "viena/elettra/**"],
    "monitor": [*VIENA, "monitor"],
    "list": [*VIENA, "list"],
    "hz": [*VIENA, "hz", "viena/elettra/sim/truth"],
    "viena-steer": STEER,
}


def one_line(run: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in run.stderr, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1, run.stderr
    return lines[0]


@pytest.mark.parametrize("tool", sorted(TOOLS))
def test_no_router_is_one_line_naming_the_endpoint_after_the_timeout(tool, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    extra = ["-o", str(tmp_path / "x.mcap")] if tool == "record" else []
    run = subprocess.run([*TOOLS[tool], *extra, "--connect", endpoint, "--timeout", "1"],
                         capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert run.returncode in (1, 2)
    line = one_line(run)
    assert f"cannot reach the router at {endpoint} in 1 s: nothing listens there" in line
    assert not (tmp_path / "x.mcap").exists() and not (tmp_path / "x.mcap.part").exists()


def test_replay_without_a_router_too(tmp_path):
    from viena.common.recording import RecordingWriter

    path = tmp_path / "one.mcap"
    writer = RecordingWriter(path)
    writer.write("viena/elettra/x", "application/json", 1, b'{"a": 1}')
    writer.close()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = viena("replay", path, "--connect", endpoint, "--timeout", "1", timeout=60)
    assert run.returncode == 1
    assert f"cannot reach the router at {endpoint} in 1 s" in one_line(run)


@pytest.mark.parametrize("tool", sorted(TOOLS))
@pytest.mark.parametrize("endpoint, says", [
    ("127.0.0.1:7447", "is not an endpoint: write PROTOCOL/HOST:PORT"),
    ("tcp/127.0.0.1", "needs HOST:PORT after tcp/"),
    ("tpc/127.0.0.1:7447", "unknown protocol 'tpc'"),
])
def test_a_malformed_endpoint_is_one_line(tool, endpoint, says, tmp_path):
    run = subprocess.run([*TOOLS[tool], "--connect", endpoint], capture_output=True, text=True,
                         timeout=60, cwd=tmp_path)
    assert run.returncode == 2
    line = one_line(run)
    assert endpoint in line and says in line


@pytest.mark.parametrize("tool", ["sub", "record", "hz", "list"])
def test_a_malformed_key_expression_is_one_line(tool, tmp_path):
    run = subprocess.run([*VIENA, tool, "viena/elettra/**/", "--connect", "tcp/127.0.0.1:9"],
                         capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert run.returncode == 2
    line = one_line(run)
    assert "'viena/elettra/**/' is not a key expression" in line and "Invalid" not in line


def test_an_unknown_host_is_named(tmp_path):
    run = viena("sub", "--connect", "tcp/no-such-host.invalid:7447", "--timeout", "1", timeout=60)
    assert run.returncode == 1
    assert "unknown host 'no-such-host.invalid'" in one_line(run)


def test_a_misspelt_key_is_said_and_records_nothing(router, tmp_path):
    sub = viena("sub", "viena/elettra/nothing/here", "--connect", router, "--timeout", "7", timeout=60)
    assert sub.returncode == 0 and sub.stdout == ""
    assert "nothing on 'viena/elettra/nothing/here' for 5 s: is the key right?" in one_line(sub)

    out = tmp_path / "drive.mcap"
    rec = viena("record", "viena/elettra/nothing/here", "--connect", router, "-o", out, "--duration", "6",
                "-q", timeout=60)
    assert rec.returncode == 1
    lines = rec.stderr.strip().splitlines()
    assert any("nothing on 'viena/elettra/nothing/here' for 5 s" in line for line in lines), rec.stderr
    assert "nothing came on 'viena/elettra/nothing/here': no file written" in lines[-1]
    assert not out.exists() and not out.with_name("drive.mcap.part").exists()


@pytest.mark.car
def test_tools_without_connect_use_the_running_profiles_endpoint(tmp_path):
    """`viena up --free-ports` saved its router's port; sub and list find it there."""
    from vienatest import sim_profile_up

    with sim_profile_up(tmp_path / "run") as (env, router):
        sub = subprocess.run([*VIENA, "sub", "viena/elettra/sim/truth", "-n", "2", "--timeout", "30"],
                             env=env, capture_output=True, text=True, timeout=90)
        assert sub.returncode == 0, sub.stderr
        assert len(sub.stdout.strip().splitlines()) == 2
        listed = subprocess.run([*VIENA, "list"], env=env, capture_output=True, text=True, timeout=90)
        assert listed.returncode == 0, listed.stderr
        assert "viena/elettra/sim/truth" in listed.stdout and "viena.sim.truth/1" in listed.stdout


def test_sub_without_timeout_still_gives_up_connecting():
    from viena.tool import CONNECT_TIMEOUT_S

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = viena("sub", "--connect", endpoint, timeout=60)
    assert run.returncode == 1
    assert f"cannot reach the router at {endpoint} in {CONNECT_TIMEOUT_S:g} s: nothing listens there" in one_line(run)
