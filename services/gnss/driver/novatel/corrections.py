"""Which differential corrections an OEM4 receiver takes, from its VERSION log's model and
firmware, by the manuals (OEM4 vol. 1 rev. 19 and vol. 2 for firmware 2.310; docs/README.md#sources).

What the manuals settle:
- every model takes pseudorange corrections (DGPS, PSRDIFF): RTCM 2.x types 1 and 9 (vol. 1
  §5.2.1, 5.2.3: "All OEM4 family receivers can accept Type 9 messages") and RTCA Type 1
  (vol. 1 §5.1.1);
- RTK needs the RT-20 (L1, floating ambiguities: L1_FLOAT) or the RT-2 (L1/L2, fixed
  ambiguities: NARROW_INT) option (vol. 2 "Conventions": the RTK tag; vol. 1 §6.5.1,
  Table 12). RT-2 also runs RT-20 when the base sends L1 only (vol. 1 §5.2: RTCM 3 and 59);
- the RTK formats: RTCM 2.x types 3, 18, 19, 20, 21, 22, 59N (vol. 2 §3.4.63), RTCA
  RTCAOBS/RTCAREF (§3.4.58), CMR (vol. 1 §5.4, "RT-2 or RT-20 mode"; CMR is an RTKSOURCE
  type only, Table 31 note b) and RTCM 3.0, types 1001-1006 and no others (vol. 1 §5.3,
  vol. 2 §3.4.73: GPS observables 1001-1004, base ARP 1005/1006);
- model names are their options: "RT2", "RT2W", "RT2WA", "RT2WLBA", "INSRT2W", "OEM4L1L2",
  "3151R", "3151W", "L1L2W" (vol. 1 §4.4, §7.5; vol. 2 AUTH, MODEL, VALIDMODELS, VERSION);
  "W" (or WAAS, EGNOS, MSAS) in the name is SBAS (vol. 1 §4.4).

What they do not settle, decided conservatively here:
- which firmware first took RTCMV3: the 2.310 manual lists it (Table 28 value 14, Table 31
  value 13) and its "What's new since 2.300" does not, so 2.300 had it; older firmware
  (the VERSION example's 2.200) is taken not to;
- whether a model without RTK uses RTCMV3 for a pseudorange solution: RTCM 3.0 messages are
  RTK observables (the RTCMV3 logs carry the RTK tag), so such a model is taken not to;
- a model name the manuals do not give (not RT2..., RT20..., L1L2..., 3151...) is taken to
  have no RTK: pseudorange formats only (the service's `corrections_check` off overrides).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

#: The formats, as INTERFACEMODE names them (Table 28), in the order they are listed.
FORMATS = ("RTCM", "RTCA", "CMR", "RTCMV3")
#: Formats every model takes for pseudorange DGPS.
PSEUDORANGE_FORMATS = ("RTCM", "RTCA")
#: Formats that carry RTK only: they need the RT-20 or RT-2 option.
RTK_ONLY_FORMATS = ("CMR", "RTCMV3")
#: The first firmware known to take RTCMV3 (see the module's docstring).
RTCMV3_FIRMWARE = (2, 300)
#: The RTCM 3 messages an OEM4 decodes (vol. 1 §5.3, vol. 2 §3.4.73).
RTCM3_DECODED = frozenset(range(1001, 1007))
#: RTCM 2.x messages an OEM4 rover uses, by what they need (vol. 2 §3.4.63, vol. 1 §5.2).
RTCM2_PSEUDORANGE = (1, 9)
RTCM2_RTK = (3, 18, 19, 20, 21, 22, 59)


@dataclass(frozen=True)
class ReceiverAbility:
    """What one receiver takes: its RTK option and the correction formats it accepts."""

    model: str                       # as VERSION gave it, e.g. "RT2WA"
    firmware: str                    # as VERSION gave it, e.g. "2.200A1"
    rtk: str = ""                    # "RT-2", "RT-20" or "" (pseudorange DGPS only)
    known_model: bool = True         # the model's name is one the manuals give
    sbas: bool = False
    formats: tuple[str, ...] = PSEUDORANGE_FORMATS

    @property
    def firmware_number(self) -> str:
        """The firmware as major.minor ("2.200"), what the manuals' thresholds compare."""
        v = firmware_version(self.firmware)
        return "?" if v is None else f"{v[0]}.{v[1]:03d}"

    def takes(self, fmt: str) -> bool:
        return fmt in self.formats

    def rtcm3_types(self) -> frozenset[int]:
        """The RTCM 3 message numbers it decodes (none unless it takes RTCMV3)."""
        return RTCM3_DECODED if self.takes("RTCMV3") else frozenset()

    def refusal(self, fmt: str) -> str:
        """Why `fmt` cannot go to this receiver, in one line's words ("" when it can):
        'model 3151R firmware 2.200 takes RTCM, RTCA (RTK needs the RT-20 or RT-2 option)'."""
        if self.takes(fmt):
            return ""
        takes = f"model {self.model or '?'} firmware {self.firmware_number} takes {', '.join(self.formats)}"
        if fmt not in FORMATS:
            return f"{takes} ({fmt!r} is not a correction format)"
        reasons = []
        if not self.known_model:
            reasons.append(f"model {self.model!r} is not one the manuals name, taken as without RTK")
        if fmt in RTK_ONLY_FORMATS and not self.rtk:
            reasons.append(f"{fmt} carries RTK, which needs the RT-20 or RT-2 option")
        if fmt == "RTCMV3" and self.rtk:
            major, minor = RTCMV3_FIRMWARE
            reasons.append(f"RTCMV3 needs firmware {major}.{minor:03d} or later")
        return f"{takes} ({'; '.join(reasons)})" if reasons else takes

    def summary(self) -> str:
        """One line for health and doctor: 'RT2WA 2.200A1: RT-2; takes RTCM, RTCA, CMR'."""
        option = self.rtk or "no RTK"
        return f"{self.model or '?'} {self.firmware or '?'}: {option}; takes {', '.join(self.formats)}"


_FIRMWARE = re.compile(r"\s*(\d+)\.(\d{1,3})")


def firmware_version(sw_version: str) -> tuple[int, int] | None:
    """(major, minor) of a VERSION 'sw version' VV.RRR[Xxxx] (Table 89): '2.200A1' ->
    (2, 200), '1.400D86' -> (1, 400); None when it is not that shape."""
    m = _FIRMWARE.match(sw_version or "")
    if m is None:
        return None
    return int(m.group(1)), int(m.group(2).ljust(3, "0"))


def rtk_option(model: str) -> tuple[str, bool]:
    """(RTK option, whether the manuals name such a model) from a model name: 'RT2WA' ->
    ('RT-2', True), 'RT20' -> ('RT-20', True), '3151R' -> ('', True), 'XYZ' -> ('', False).
    An 'OEM4' prefix (AUTH's 'OEM4L1L2', 'oem4rt2') and SPAN's 'INS' are not the option."""
    name = (model or "").strip().upper()
    for prefix in ("OEM4-", "OEM4", "INS"):
        if name.startswith(prefix):
            name = name[len(prefix):]
    if name.startswith("RT20"):
        return "RT-20", True
    if name.startswith("RT2"):
        return "RT-2", True
    if name.startswith(("L1L2", "3151")):
        return "", True
    return "", False


def has_sbas(model: str) -> bool:
    """SBAS-capable: a W, WAAS, MSAS or EGNOS in the model name (vol. 1 §4.4)."""
    name = (model or "").upper().removeprefix("OEM4")
    return any(word in name for word in ("W", "EGNOS", "MSAS"))


def ability(model: str, sw_version: str) -> ReceiverAbility:
    """What a receiver of this model and firmware takes (see the module's docstring)."""
    option, known = rtk_option(model)
    formats = list(PSEUDORANGE_FORMATS)
    if option:
        formats.append("CMR")
        version = firmware_version(sw_version)
        if version is not None and version >= RTCMV3_FIRMWARE:
            formats.append("RTCMV3")
    return ReceiverAbility(model=model, firmware=sw_version, rtk=option, known_model=known,
                           sbas=has_sbas(model), formats=tuple(formats))


def ability_of_version(version) -> ReceiverAbility | None:
    """The ability of a VERSION log's GPSCARD component; None when it has none."""
    card = version.card
    if card is None:
        return None
    return ability(card.model, card.sw_version)
