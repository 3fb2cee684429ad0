"""Whether the receiver does SBAS as it was asked, in its own words (docs/sensors.md#sbas).

The OEM4 2.310 manual's table gives SBASCONTROL's keyword as ENABLE 0, DISABLE 1; every
other ENABLE/DISABLE in that manual, and later NovAtel firmware, number them the other
way. A binary command cannot tell which a receiver reads, and an OK response only says the
command was taken. What the receiver then holds is in its RXCONFIG log, which in ASCII
names the keyword (ENABLE or DISABLE), so that is what confirms the setting: asked at the
end of the start-up (`StartupConfig.read_config`), compared here. Whether corrections are
actually used shows in the fixes: position type WAAS (once a GEO satellite is tracked).
"""
from __future__ import annotations

from dataclasses import dataclass

from .ascii import ConfigEntry
from .enums import SbasTestMode

CONFIRMED, MISMATCH, WAITING, UNCONFIRMED = "confirmed", "mismatch", "waiting", "unconfirmed"


@dataclass(frozen=True)
class SbasCheck:
    verdict: str                    # CONFIRMED, MISMATCH, WAITING or UNCONFIRMED
    wanted: str                     # what was asked, as RXCONFIG would write it ("": left alone)
    reported: str | None            # what the receiver's RXCONFIG says (None: nothing yet)
    why: str = ""

    @property
    def confirmed(self) -> bool | None:
        """True or False once known; None while waiting."""
        return None if self.verdict == WAITING else self.verdict == CONFIRMED


def wanted_sbas(config) -> str:
    """SBASCONTROL as a StartupConfig asks for it, in RXCONFIG's words ("" if it does not)."""
    if config.sbas is None:
        return ""
    return (f"{config.sbas.name} {config.sbas_system.name} {config.sbas_prn} "
            f"{SbasTestMode(config.sbas_testmode).name}")


def check_sbas(config, reported: ConfigEntry | None, *, waited_s: float, wait_s: float,
               request_error: str = "") -> SbasCheck:
    """Compare the start-up's SBASCONTROL (`config`, a StartupConfig) with what the receiver
    reported; without a report, WAITING until `wait_s` have passed since the start-up."""
    wanted = wanted_sbas(config)
    if reported is None:
        if request_error:
            return SbasCheck(UNCONFIRMED, wanted, None, f"RXCONFIG refused: {request_error}")
        if waited_s < wait_s:
            return SbasCheck(WAITING, wanted, None)
        return SbasCheck(UNCONFIRMED, wanted, None, f"no RXCONFIG within {wait_s:g} s")
    said = " ".join(reported.fields)
    if not wanted or said == wanted:
        return SbasCheck(CONFIRMED, wanted, said)
    why = f"SBASCONTROL {wanted} was sent, the receiver holds {said}"
    if reported.fields[:1] != (config.sbas.name,):
        why += (f" (binary keyword {config.sbas_enable_value} for ENABLE: if the firmware "
                f"reads it the other way, set sbas_enable_value = {1 - config.sbas_enable_value})")
    return SbasCheck(MISMATCH, wanted, said, why)
