"""The trip table (model/trips.py): the one list of why the steering stops, checked against
docs/steering.md, the settings it names and the texts the core writes; and the model rooms
load no I/O stack."""
from __future__ import annotations

import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import pytest
from canopen.profiles.p402 import State402

from viena.services.steering.model import ds402
from viena.services.steering.model.trips import TRIPS, TripCause, markdown_table, trip, trip_text
from viena.services.steering.service import SteeringSettings

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "steering.md"
BEGIN, END = "<!-- trips: begin (model/trips.py markdown_table) -->", "<!-- trips: end -->"
MODEL = REPO / "services" / "steering" / "model"


def test_every_cause_has_one_row():
    assert [row.cause for row in TRIPS] == list(TripCause)


def test_the_doc_shows_the_codes_table():
    text = DOC.read_text()
    table = text.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n") + "\n"
    assert table == markdown_table(), "docs/steering.md#watchdog-and-trips: paste model/trips.py markdown_table()"


def test_each_deadline_is_a_steering_setting():
    for row in TRIPS:
        if row.deadline is None:
            continue
        part, name = row.deadline.split(".")
        settings = getattr(SteeringSettings(), part)
        assert name in {f.name for f in fields(settings)}, (row.cause, row.deadline)


@pytest.mark.parametrize("cause", list(TripCause))
def test_the_text_begins_with_the_label(cause):
    assert trip_text(cause, ": detail").startswith(trip(cause).label)
    assert trip_text(cause) == trip(cause).label


def test_the_ds402_words_are_canopens():
    assert ds402.SW_MASK == State402.SW_MASK
    assert (ds402.CW_DISABLE_VOLTAGE, ds402.CW_QUICK_STOP, ds402.CW_SHUTDOWN, ds402.CW_SWITCH_ON,
            ds402.CW_ENABLE_OPERATION) == (State402.CW_DISABLE_VOLTAGE, State402.CW_QUICK_STOP,
                                           State402.CW_SHUTDOWN, State402.CW_SWITCH_ON,
                                           State402.CW_OPERATION_ENABLED)


def test_the_twins_transitions_are_canopens():
    """Every transition canopen's State402 commands reaches, by its controlword, the state
    canopen expects in the twin's table; the table has no transition canopen lacks but the
    EPOS's own shortcuts (ready -> enabled, ready/switched on -> disabled by a quick stop)."""
    for (start, end), cw in State402.TRANSITIONTABLE.items():
        if start in ("START", ds402.NOT_READY, ds402.FAULT_REACTION):    # automatic ones
            continue
        previous = 0 if cw & ds402.CW_FAULT_RESET else ds402.CW_ENABLE_OPERATION
        assert ds402.next_state(start, ds402.command_of(cw, previous)) == end, (start, end, hex(cw))
    canopens = {(start, end) for start, end in State402.TRANSITIONTABLE}
    shortcuts = {(ds402.READY, ds402.OPERATION_ENABLED), (ds402.READY, ds402.SWITCH_ON_DISABLED),
                 (ds402.SWITCHED_ON, ds402.SWITCH_ON_DISABLED)}
    ours = {(start, end) for moves in ds402.TRANSITIONS.values() for start, end in moves.items()}
    assert ours - canopens <= shortcuts


def test_a_fault_reset_acts_on_the_edge_only():
    assert ds402.command_of(ds402.CW_FAULT_RESET, 0) == ds402.FAULT_RESET
    assert ds402.command_of(ds402.CW_FAULT_RESET | ds402.CW_ENABLE_OPERATION, ds402.CW_FAULT_RESET) is None
    assert ds402.next_state(ds402.FAULT, ds402.command_of(ds402.CW_SHUTDOWN)) == ds402.FAULT
    assert ds402.next_state(ds402.FAULT_REACTION, ds402.command_of(0)) == ds402.FAULT_REACTION


@pytest.mark.parametrize("module", sorted(p.stem for p in MODEL.glob("*.py") if p.stem != "__init__"))
def test_a_model_module_loads_no_io_stack(module):
    """Imported alone, in a fresh interpreter."""
    code = (f"import sys, viena.services.steering.model.{module}; "
            "print([m for m in ('serial', 'can', 'canopen', 'pynmea2', 'zenoh') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", (module, out)


def test_the_cores_life_guard_code_is_the_drivers():
    """The core names the drive's life-guard EMCY without importing the driver (a model loads
    no I/O): the two must stay the same number, or a life-guard stop reads as a fault."""
    from viena.services.steering.driver.emcy import LIFE_GUARD_ERROR
    from viena.services.steering.model import core
    assert core.LIFE_GUARD_ERROR == LIFE_GUARD_ERROR == 0x8130
