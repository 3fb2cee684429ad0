"""`viena foxglove --max-rate HZ`: at most HZ samples a second per key, on a given clock."""
from __future__ import annotations

from viena.foxglove import Downsampler


def test_at_most_the_rate_per_key_and_every_key_on_its_own():
    thin = Downsampler(10.0)
    kept = [t for t in (i * 0.01 for i in range(1000)) if thin.keep("truth", t)]    # 100 Hz for 10 s
    assert len(kept) == 100 and kept[0] == 0.0
    assert all(b - a > 0.1 - 0.01 - 1e-9 for a, b in zip(kept, kept[1:]))     # within one input step
    assert thin.keep("fix", 0.995)                                  # another key: its own budget
    assert not thin.keep("truth", kept[-1] + 0.05)


def test_zero_keeps_everything_and_a_pause_does_not_make_a_burst():
    everything = Downsampler(0.0)
    assert all(everything.keep("k", i * 1e-4) for i in range(1000))
    thin = Downsampler(10.0)
    assert thin.keep("k", 0.0)
    assert thin.keep("k", 5.0)                                      # after a silence: one sample,
    assert not thin.keep("k", 5.01)                                 # not the 50 it "missed"
