"""The Foxglove tests share the laptop tests' offline drive (tests/laptop/laptop_helpers.py)."""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "laptop"))
