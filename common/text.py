"""Text from clients, made safe to echo: into a state every subscriber reads, or a log.

A field name or a reason built from a client's bytes may be 3 KB long or carry terminal
escape codes; what is shown of it is printable ASCII and short, enough to find the mistake.
"""
from __future__ import annotations

#: the longest piece of a client's text that is shown back
SHOWN_CHARS = 40


def printable(text: object, limit: int = SHOWN_CHARS) -> str:
    """`text` as printable ASCII: anything else becomes '?', and past `limit` characters
    the rest is cut and counted ("abc... (+3000 chars)")."""
    text = str(text)
    shown = "".join(c if " " <= c <= "~" else "?" for c in text[:limit])
    return shown if len(text) <= limit else f"{shown}... (+{len(text) - limit} chars)"
