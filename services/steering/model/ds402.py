"""The DS402 device control words as the EPOS uses them (firmware specification §8.1).

Written out in docs/steering.md#ds402-states; section and table numbers are the EPOS firmware
specification's (docs/README.md#sources).

The state names, statusword masks and controlword commands are canopen's
(`canopen.profiles.p402.State402`), written out here so that the model imports no CAN stack
(tests/steering/test_steering_trips.py checks they still equal canopen's): the service, the
twin and canopen's BaseNode402 speak of the same states. This module adds the EPOS
statusword values and the controlword commands by name.
"""
from __future__ import annotations

NOT_READY = "NOT READY TO SWITCH ON"
SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
READY = "READY TO SWITCH ON"
SWITCHED_ON = "SWITCHED ON"
OPERATION_ENABLED = "OPERATION ENABLED"
QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
FAULT_REACTION = "FAULT REACTION ACTIVE"
FAULT = "FAULT"
UNKNOWN = "UNKNOWN"

#: controlword commands (low byte; firmware specification table 3)
CW_DISABLE_VOLTAGE = 0x0000                           # -> switch on disabled
CW_QUICK_STOP = 0x0002                                # -> quick stop active
CW_SHUTDOWN = 0x0006                                  # -> ready to switch on
CW_SWITCH_ON = 0x0007                                 # -> switched on
CW_ENABLE_OPERATION = 0x000F                          # -> operation enabled
CW_FAULT_RESET = 0x0080                               # bit 7; acts on its 0 -> 1 edge only

#: the commands a controlword gives (CiA 402; firmware specification table 3), by name
DISABLE_VOLTAGE = "DISABLE VOLTAGE"
QUICK_STOP = "QUICK STOP"
SHUTDOWN = "SHUTDOWN"
SWITCH_ON = "SWITCH ON"                  # also "disable operation" from operation enabled
ENABLE_OPERATION = "ENABLE OPERATION"    # also "switch on + enable operation" from ready
FAULT_RESET = "FAULT RESET"              # the 0 -> 1 edge of bit 7

#: controlword -> command: the first (mask, bits) the low bits match, in this order. While
#: bit 7 is set the controlword commands nothing but, on its rising edge, a fault reset.
CW_COMMANDS = (
    (0x02, 0x00, DISABLE_VOLTAGE),
    (0x06, 0x02, QUICK_STOP),
    (0x07, 0x06, SHUTDOWN),
    (0x0F, 0x07, SWITCH_ON),
    (0x0F, 0x0F, ENABLE_OPERATION),
)

#: statusword bits the EPOS sets besides the state (table 101)
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5            # 1 = no quick stop in progress
SW_WARNING = 1 << 7
SW_OFFSET_CURRENT_MEASURED = 1 << 8
SW_REMOTE = 1 << 9                # NMT operational
SW_TARGET_REACHED = 1 << 10
SW_FOLLOWING_ERROR = 1 << 13

#: the state bits of the statusword as the EPOS reports each state (table 1 and the
#: values the original VIENA code read from the car's drive)
EPOS_STATUSWORD = {
    NOT_READY: 0x0000,
    SWITCH_ON_DISABLED: 0x0140,
    READY: 0x0121,
    SWITCHED_ON: 0x0123,
    OPERATION_ENABLED: 0x0137,
    QUICK_STOP_ACTIVE: 0x0117,
    FAULT_REACTION: 0x011F,
    FAULT: 0x0108,
}


#: command -> {state: the state it takes it to}: the device control state machine (firmware
#: specification figure 2; the numbers are CiA 402's transitions, as in canopen's
#: State402.TRANSITIONTABLE). A command a state has no entry for changes nothing; FAULT
#: REACTION ACTIVE leaves by itself (14) once the drive has stopped, and FAULT only by a fault
#: reset no error outlives (15).
TRANSITIONS: dict[str, dict[str, str]] = {
    DISABLE_VOLTAGE: dict.fromkeys((READY, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE),
                                   SWITCH_ON_DISABLED),                                   # 7, 10, 9, 12
    QUICK_STOP: {READY: SWITCH_ON_DISABLED, SWITCHED_ON: SWITCH_ON_DISABLED,              # 7, 10
                 OPERATION_ENABLED: QUICK_STOP_ACTIVE},                                   # 11
    SHUTDOWN: dict.fromkeys((SWITCH_ON_DISABLED, SWITCHED_ON, OPERATION_ENABLED), READY),  # 2, 6, 8
    SWITCH_ON: dict.fromkeys((READY, OPERATION_ENABLED), SWITCHED_ON),                    # 3, 5 (disable operation)
    ENABLE_OPERATION: dict.fromkeys((READY, SWITCHED_ON, QUICK_STOP_ACTIVE),              # 3 + 4, 4, 16
                                    OPERATION_ENABLED),
    FAULT_RESET: {FAULT: SWITCH_ON_DISABLED},                                             # 15
}

#: where a fault takes a moving drive: it first stops (fault reaction, 13); any other state is
#: in fault at once, and a drive already reacting goes on stopping
FAULT_FROM = {OPERATION_ENABLED: FAULT_REACTION, QUICK_STOP_ACTIVE: FAULT_REACTION}

#: the states with the power stage off: the motor holds nothing, the wheel turns by hand
POWER_STAGE_OFF = frozenset({NOT_READY, SWITCH_ON_DISABLED, READY, SWITCHED_ON, FAULT})


def command_of(controlword: int, previous: int = 0) -> str | None:
    """The command a controlword gives after `previous` (None: none)."""
    if controlword & CW_FAULT_RESET:
        return None if previous & CW_FAULT_RESET else FAULT_RESET
    for mask, bits, command in CW_COMMANDS:
        if controlword & mask == bits:
            return command
    return None


def next_state(state: str, command: str | None) -> str:
    """The state a command takes `state` to (itself when the table has no such transition)."""
    return state if command is None else TRANSITIONS[command].get(state, state)

#: state -> (mask, bits) of the statusword: canopen's State402.SW_MASK (CiA 402)
SW_MASK = {
    NOT_READY: (0x4F, 0x00),
    SWITCH_ON_DISABLED: (0x4F, 0x40),
    READY: (0x6F, 0x21),
    SWITCHED_ON: (0x6F, 0x23),
    OPERATION_ENABLED: (0x6F, 0x27),
    FAULT: (0x4F, 0x08),
    FAULT_REACTION: (0x4F, 0x0F),
    QUICK_STOP_ACTIVE: (0x6F, 0x07),
}


def state_of(statusword: int) -> str:
    """The DS402 state a statusword reports (canopen's masks)."""
    for state, (mask, bits) in SW_MASK.items():
        if statusword & mask == bits:
            return state
    return UNKNOWN


def is_enabled(statusword: int) -> bool:
    """Power applied and following setpoints."""
    return state_of(statusword) == OPERATION_ENABLED


def is_fault(statusword: int) -> bool:
    return state_of(statusword) in (FAULT, FAULT_REACTION)
