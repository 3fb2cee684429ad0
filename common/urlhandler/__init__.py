"""pyserial URL handlers of viena's own, laid out as pyserial's (`protocol_<scheme>.py`).

`use()` puts them ahead of pyserial's in this process: `serial.serial_for_url()` then
opens, for instance, `socket://` with `protocol_socket.Serial` here."""
from __future__ import annotations

import serial


def use() -> None:
    if __name__ not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.insert(0, __name__)
