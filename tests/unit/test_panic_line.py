"""The panic line (ether_ros.ros.panic_line) and its native key reader (crates/commands
panic_keys): a real rclpy `panic` service in this process, a pipe as the terminal."""

from __future__ import annotations

import os
import threading
import uuid
from collections.abc import Iterator

import pytest
import rclpy
import rclpy.executors
from rclpy.context import Context
from std_srvs.srv import Trigger

from ether_ros.ros.panic_line import PanicLine
from ether_ros.ros.rig import domain_for
from ether_ros.testing.wait import wait_for


class PanicService:
    """A stand-in for the node's `panic` service: counts the requests it served."""

    def __init__(self, context: Context, prefix: str) -> None:
        self.calls = 0
        self.node = rclpy.create_node(f"panic_service_{uuid.uuid4().hex[:8]}", context=context)
        self.node.create_service(Trigger, f"{prefix}panic", self._serve)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _serve(self, _req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.calls += 1
        resp.success, resp.message = True, f"safe outputs on the wire ({self.calls})"
        return resp

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1)
        self.node.destroy_node()


@pytest.fixture
def context() -> Iterator[Context]:
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_for(os.getpid(), 11))
    yield ctx
    ctx.try_shutdown()


def test_a_press_is_answered_and_reported_with_the_hint(context: Context) -> None:
    prefix = f"/t{uuid.uuid4().hex[:8]}/"
    service = PanicService(context, prefix)
    reports: list[str] = []
    line = PanicLine(prefix, context, report=reports.append, hint="type 'clear'")
    interrupted: list[bool] = []
    line.on_press.append(lambda: interrupted.append(True))
    try:
        assert line.ready(timeout=20)
        answer = line.press()
        assert answer.wait(20) and answer.ok
        assert service.calls == 1 and interrupted == [True]
        assert reports == ["PANIC: safe outputs on the wire (1); type 'clear'"]
        line.press(hooks=False).wait(20)
        assert interrupted == [True]  # a panic that is a command does not interrupt itself
    finally:
        line.close()
        service.close()


def test_without_the_service_a_press_fails_with_a_reason(context: Context) -> None:
    reports: list[str] = []
    line = PanicLine(f"/nobody{uuid.uuid4().hex[:8]}/", context, report=reports.append)
    line.answer_timeout = 0.5
    try:
        answer = line.press()
        assert answer.wait(20) and not answer.ok
        assert "panic service" in answer.message and "not available" in answer.message
        assert reports[-1].startswith("panic FAILED: ")
    finally:
        line.close()


def test_the_native_key_reader_sends_the_panic_and_passes_every_byte_on(
    context: Context,
) -> None:
    """The terminal is a pipe here: the native reader sends the request on the panic line's
    client when Ctrl-P arrives (also an F1 split across two reads), and forwards the bytes
    unchanged; claim_keys picks up the requests and their answers."""
    prefix = f"/t{uuid.uuid4().hex[:8]}/"
    service = PanicService(context, prefix)
    reports: list[str] = []
    line = PanicLine(prefix, context, report=reports.append)
    term_r, term_w = os.pipe()
    fwd_r = -1
    try:
        assert line.ready(timeout=20)
        keys = line.watch_terminal(term_r)
        assert keys is not None
        fwd_r = keys
        os.write(term_w, b"set hind\x10_leg")
        wait_for("the native reader's request", lambda: service.calls == 1)
        forwarded = b""
        while len(forwarded) < len(b"set hind\x10_leg"):
            forwarded += os.read(fwd_r, 100)
        assert forwarded == b"set hind\x10_leg"
        (answer,) = line.claim_keys()
        assert answer.wait(20) and answer.ok
        os.write(term_w, b"\x1bO")  # F1, split across two reads
        wait_for("the first half on the pipe", lambda: os.read(fwd_r, 100) == b"\x1bO")
        assert service.calls == 1
        os.write(term_w, b"P")
        wait_for("the second request", lambda: service.calls == 2)
        assert len(line.claim_keys()) == 1
        wait_for("both answers reported", lambda: len(reports) == 2)
        assert line.claim_keys() == []
    finally:
        line.close()  # stops the reader, which closes its end of the forward pipe
        if fwd_r >= 0:
            assert os.read(fwd_r, 100) in (b"P", b"")
            os.close(fwd_r)
        for fd in (term_r, term_w):
            os.close(fd)
        service.close()
