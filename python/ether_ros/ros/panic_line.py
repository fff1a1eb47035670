"""A path of its own to the node's ``panic`` service, for the operator tools (console, ``top``).

A panic must not wait for anything the tool is busy with. The general client
(:class:`ether_ros.ros.client.EtherRosClient`) shares one executor thread between high-rate
topic callbacks and every service answer, and its calls block their caller until the answer
comes; a tool's command worker may be inside such a call when the operator hits the panic key.
So the panic request goes its own way:

- its own rclpy node, in the same context as the tool's client (hence the same DDS participant:
  nothing to discover again), with one ``std_srvs/Trigger`` client and an executor thread that
  serves nothing but the panic answers;
- :meth:`PanicLine.press` sends the request from the calling thread (the key reader's) and
  returns at once — the request is on its way before anything else is looked at; no lock of
  the general client is taken;
- the answer, or its absence after ``answer_timeout``, is reported (``report``) when it comes.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import rclpy
import rclpy.executors
from rclpy.context import Context
from std_srvs.srv import Trigger

_names = itertools.count()


class PanicAnswer:
    """One panic request; :meth:`wait` for the node's answer."""

    def __init__(self) -> None:
        self.pressed_at = time.monotonic()
        self._done = threading.Event()
        self.ok = False
        self.message = ""

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def settle(self, ok: bool, message: str) -> None:
        self.ok, self.message = ok, message
        self._done.set()

    def wait(self, timeout: float) -> bool:
        """True once the node answered (or the request failed) within ``timeout`` s."""
        return self._done.wait(timeout)


class PanicLine:
    """Sends ``panic`` to the node whose services live under ``prefix`` (``""`` or
    ``"/robot/"``); ``report`` gets one line per answer; ``hint`` is appended to a
    successful one (what the operator types to clear it)."""

    def __init__(
        self,
        prefix: str = "",
        context: Context | None = None,
        report: Callable[[str], None] = print,
        hint: str = "",
        answer_timeout: float = 3.0,
    ) -> None:
        self.service = f"{prefix}panic"
        self.report = report
        self.hint = hint
        self.answer_timeout = answer_timeout
        self.presses = 0
        self.last_press = 0.0  # time.monotonic() of the last press (0: never)
        # Called right after a press sent its request (a tool interrupts its running command).
        self.on_press: list[Callable[[], None]] = []
        self._lock = threading.Lock()
        self._closed = False
        name = f"ether_ros_panic_{os.getpid()}_{next(_names)}"
        self._node = rclpy.create_node(name, context=context, start_parameter_services=False)
        self._client: Any = self._node.create_client(Trigger, self.service)
        self._executor = rclpy.executors.SingleThreadedExecutor(context=context)
        self._executor.add_node(self._node)
        self._thread = threading.Thread(target=self._spin, name="ether_ros-panic", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        with contextlib.suppress(Exception):  # the context was shut down while spinning
            self._executor.spin()

    def ready(self, timeout: float = 0.0) -> bool:
        """The node's panic service is discovered (waits up to ``timeout`` s)."""
        if self._client.service_is_ready():
            return True
        return timeout > 0 and bool(self._client.wait_for_service(timeout_sec=timeout))

    def press(self, hooks: bool = True) -> PanicAnswer:
        """Send the panic request now; never blocks. The answer is reported when it comes.
        ``hooks``: call the ``on_press`` hooks (a tool's running command is interrupted)."""
        answer = PanicAnswer()
        with self._lock:
            self.presses += 1
            self.last_press = answer.pressed_at
            closed = self._closed
        if closed:
            self._settle(answer, False, "the panic line is closed")
        elif self._client.service_is_ready():
            self._send(answer)
        else:  # not discovered (yet): wait for it away from the caller
            threading.Thread(target=self._send_when_ready, args=(answer,), daemon=True).start()
        for hook in list(self.on_press) if hooks else ():
            hook()
        return answer

    def _send_when_ready(self, answer: PanicAnswer) -> None:
        if self.ready(self.answer_timeout):
            self._send(answer)
        else:
            self._settle(
                answer,
                False,
                f"the node's panic service {self.service} is not available (is the node running?)",
            )

    def _send(self, answer: PanicAnswer) -> None:
        try:
            future = self._client.call_async(Trigger.Request())
        except Exception as exc:  # the context is gone
            self._settle(answer, False, f"cannot send: {exc}")
            return
        future.add_done_callback(lambda f: self._answered(answer, f))
        timer = threading.Timer(self.answer_timeout, self._late, args=(answer,))
        timer.daemon = True
        timer.start()

    def _answered(self, answer: PanicAnswer, future: Any) -> None:
        try:
            response = future.result()
            ok, message = bool(response.success), str(response.message)
        except Exception as exc:
            ok, message = False, str(exc) or type(exc).__name__
        late = answer.done  # already reported as unanswered
        self._settle(answer, ok, message, late=late)

    def _late(self, answer: PanicAnswer) -> None:
        if not answer.done:
            self.report(
                f"panic: sent, but the node has not answered within {self.answer_timeout:g} s "
                "— it may not have taken effect: check the machine"
            )
            answer.settle(False, "no answer")

    def _settle(self, answer: PanicAnswer, ok: bool, message: str, late: bool = False) -> None:
        answer.settle(ok, message)
        if ok:
            hint = f"; {self.hint}" if self.hint else ""
            self.report(f"PANIC{' (late answer)' if late else ''}: {message}{hint}")
        else:
            self.report(f"panic FAILED: {message}")

    def close(self) -> None:
        with self._lock:
            self._closed = True
        with contextlib.suppress(Exception):
            self._executor.shutdown(timeout_sec=1.0)
        with contextlib.suppress(Exception):
            self._node.destroy_node()
        self._thread.join(timeout=2)
