"""What the fault tests ask of a refusal: one line on stderr, never a traceback."""

from __future__ import annotations


def one_line(err: str) -> str:
    """The one non-blank line of ``err``; fails the test with all of ``err`` otherwise."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]
