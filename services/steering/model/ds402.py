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
