"""The console's key guard: panic keys first, Ctrl-C for the running command, bounded lines and
pastes (ether_ros.console.keys). The filter is pure; the guard runs on real pipes."""

from __future__ import annotations

import os
import threading

import pytest

from ether_ros.console.keys import (
    LINE_LIMIT,
    PASTE_END,
    PASTE_START,
    KeyFilter,
    KeyGuard,
)
from ether_ros.testing.wait import wait_for


@pytest.mark.parametrize("key", [b"\x10", b"\x1bOP", b"\x1b[11~", b"\x1b[[A"])
def test_a_panic_key_anywhere_in_a_chunk_is_taken_out_and_reported(key: bytes) -> None:
    f = KeyFilter()
    out = f.feed(b"set hind" + key + b"_leg", busy=False)
    assert out.panic
    assert out.forward == b"set hind_leg"
    assert not f.feed(b"set", busy=False).panic


def test_ctrl_c_interrupts_a_running_command_and_goes_to_an_idle_prompt() -> None:
    f = KeyFilter()
    busy = f.feed(b"ab\x03cd", busy=True)
    assert busy.interrupt and busy.forward == b"abcd"
    idle = f.feed(b"\x03", busy=False)
    assert not idle.interrupt and idle.forward == b"\x03"


def test_an_overlong_line_is_refused_up_to_its_end_and_nothing_of_it_is_run() -> None:
    f = KeyFilter()
    forwarded = bytearray()
    refusals = []
    for _ in range(100):  # a 100k-character paste without brackets, as a pty delivers it
        out = f.feed(b"x" * 1000, busy=False)
        forwarded += out.forward
        if out.refused:
            refusals.append(out)
    assert len(forwarded) <= LINE_LIMIT
    assert len(refusals) == 1 and refusals[0].clear_line
    assert "longer than 1024 bytes" in refusals[0].refused
    end = f.feed(b"xxx\r", busy=False)
    assert end.forward == b""  # the Enter that ends the refused line is dropped too
    assert f.feed(b"states\r", busy=False).forward == b"states\r"


def test_quiet_input_ends_a_refused_line_without_a_line_end() -> None:
    f = KeyFilter(limit=10)
    assert f.feed(b"x" * 20, busy=False).refused
    assert f.feed(b"more", busy=False).forward == b""
    f.quiet()
    assert f.feed(b"stats", busy=False).forward == b"stats"


def test_cursor_keys_do_not_count_as_line_text() -> None:
    f = KeyFilter(limit=10)
    out = f.feed(b"\x1b[A" * 50 + b"states", busy=False)
    assert not out.refused and out.forward.endswith(b"states")


def test_a_short_one_line_paste_goes_through_with_its_brackets() -> None:
    f = KeyFilter()
    out = f.feed(PASTE_START + b"set all b_ellipse100=4" + PASTE_END, busy=False)
    assert out.forward == PASTE_START + b"set all b_ellipse100=4" + PASTE_END
    assert not out.refused


def test_a_long_paste_is_refused_whole_and_a_panic_key_after_it_still_acts() -> None:
    f = KeyFilter()
    chunks = [PASTE_START + b"y" * 4000] + [b"y" * 4096] * 24 + [b"y" * 10 + PASTE_END + b"\x10"]
    outs = [f.feed(chunk, busy=False) for chunk in chunks]
    assert b"".join(o.forward for o in outs) == b""
    assert sum(bool(o.refused) for o in outs) == 1
    assert "paste refused" in next(o.refused for o in outs if o.refused)
    assert outs[-1].panic
    assert f.feed(b"stats\r", busy=False).forward == b"stats\r"


def test_a_paste_of_several_lines_is_refused() -> None:
    f = KeyFilter()
    out = f.feed(PASTE_START + b"start\nset all b_ellipse100=4\n" + PASTE_END, busy=False)
    assert out.forward == b""
    assert "2 lines" in out.refused and "sequence file" in out.refused


def test_the_guard_acts_on_panic_ahead_of_a_100k_paste() -> None:
    """A real pipe as the terminal: 100k characters then Ctrl-P; the guard reports the panic
    and the refusal, and the prompt's pipe gets no more than one line's worth."""
    term_r, term_w = os.pipe()
    prompt_r, prompt_w = os.pipe()
    events: list[str] = []
    ended = threading.Event()
    guard = KeyGuard(
        term_r,
        prompt_w,
        busy=lambda: False,
        on_panic=lambda: events.append("panic"),
        on_interrupt=lambda: events.append("interrupt"),
        on_refused=lambda message, _clear: events.append(message),
        on_end=ended.set,
    )
    guard.start()
    try:
        writer = threading.Thread(target=os.write, args=(term_w, b"z" * 100_000 + b"\x10"))
        writer.start()
        wait_for("the panic key", lambda: "panic" in events)
        writer.join(10)
        assert any("line refused" in e for e in events)
        os.set_blocking(prompt_r, False)
        try:
            reached_prompt = os.read(prompt_r, 1 << 20)
        except BlockingIOError:
            reached_prompt = b""
        assert len(reached_prompt) <= LINE_LIMIT
        os.close(term_w)  # the terminal hangs up
        wait_for("the guard to end", ended.is_set)
    finally:
        guard.stop()
        for fd in (term_r, prompt_r, prompt_w):
            os.close(fd)
