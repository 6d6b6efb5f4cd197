"""Settings of the fuzz suite (the hypothesis tests of bad input): seeded and a few seconds
each in the test run; ``FERROSLAM_FUZZ_SCALE=N`` multiplies every test's examples by N and
draws fresh random ones (the longer run documented in docs/usage.md).

Each generated case runs under a watchdog: a case that hangs longer than ``per_case_s``
ends the process with every thread's stack printed (``faulthandler``), so a hang fails the
run loudly instead of stalling it.
"""

from __future__ import annotations

import faulthandler
import functools
import os

import pytest
from hypothesis import settings

FUZZ_SCALE = int(os.environ.get("FERROSLAM_FUZZ_SCALE", "1"))


def fuzz(max_examples: int, *, per_case_s: float = 60.0, **options):
    """Decorator placed below ``@given``: ``max_examples`` (times ``FUZZ_SCALE``) cases,
    derandomised unless scaled, each under the hang watchdog; ``options`` are hypothesis
    settings (deadline, suppress_health_check)."""

    def decorate(test):
        @functools.wraps(test)
        def guarded(*args, **kwargs):
            faulthandler.dump_traceback_later(per_case_s, exit=True)
            try:
                return test(*args, **kwargs)
            finally:
                faulthandler.cancel_dump_traceback_later()

        scaled = settings(max_examples=max_examples * FUZZ_SCALE,
                          derandomize=FUZZ_SCALE == 1, **options)
        return pytest.mark.fuzz(scaled(guarded))

    return decorate
