"""sdhn_base.polling.wait_until: true as soon as the condition holds, else its last look."""

from __future__ import annotations

from sdhn_base.polling import wait_until


def test_returns_true_once_the_condition_holds_and_stops_polling() -> None:
    calls: list[int] = []

    def third_time() -> bool:
        calls.append(1)
        return len(calls) >= 3

    assert wait_until(third_time, timeout=60, poll=0.001)
    assert len(calls) == 3, f"polled {len(calls)} times after the condition held"


def test_a_condition_that_never_holds_is_false_after_a_last_look() -> None:
    calls: list[int] = []

    def never() -> bool:
        calls.append(1)
        return False

    assert not wait_until(never, timeout=0.0)
    assert len(calls) == 1, "the last look after the deadline"

