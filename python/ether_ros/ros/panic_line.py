"""A path of its own to the node's ``panic`` service, for the operator tools (console, ``top``).

A panic must not wait for anything the tool is busy with. The general client
(:class:`ether_ros.ros.client.EtherRosClient`) shares one executor thread between high-rate
topic callbacks and every service answer, and its calls block their caller until the answer
comes; a tool's command worker may be inside such a call when the operator hits the panic key.
So the panic request goes its own way:

- its own rclpy node, in the same context as the tool's client (hence the same DDS participant:
  nothing to discover again), with one ``std_srvs/Trigger`` client that no executor spins;
- :meth:`PanicLine.press` sends the request from the calling thread and returns at once;
- on a terminal, the console goes further: :meth:`PanicLine.watch_terminal` starts the native
  key reader (``ether_ros._native.PanicKeys``), which sends the request on this same client the
  moment a panic key arrives, without Python and its GIL; :meth:`PanicLine.claim_keys` then
  picks up what it sent;
- one thread of its own takes the answers off the client (a wait set on that client alone) and
  matches them to the requests by sequence number; each answer, or its absence after
  ``answer_timeout``, is reported (``report``) when it comes.
"""

from __future__ import annotations

import contextlib
import fcntl
import itertools
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from std_srvs.srv import Trigger

from ether_ros.config.bus import RosConfig

_names = itertools.count()
_WAIT_NS = 200_000_000
# SCHED_FIFO priority of the native key reader when the process may have it (CAP_SYS_NICE):
# the node's default for its own command path (ros.command_priority), below real-time threads.
KEY_READER_PRIORITY = int(RosConfig.model_fields["command_priority"].default)
# The pipe from the native key reader on: Linux's largest pipe without privileges
# (/proc/sys/fs/pipe-max-size).
KEYS_PIPE_BYTES = 1 << 20  # how long the answer thread waits before looking at its stop flag


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
        self._pending: dict[int, PanicAnswer] = {}  # sequence number -> its request
        self._early: dict[int, tuple[bool, str]] = {}  # answers to requests not claimed yet
        self._closed = False
        self._keys: Any = None  # the native key reader, while it runs
        name = f"ether_ros_panic_{os.getpid()}_{next(_names)}"
        self._node = rclpy.create_node(name, context=context, start_parameter_services=False)
        self._client: Any = self._node.create_client(Trigger, self.service)
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._take_answers, name="ether_ros-panic", daemon=True
        )
        self._thread.start()

    # ------------------------------------------------------------------ sending
    def ready(self, timeout: float = 0.0) -> bool:
        """The node's panic service is discovered (waits up to ``timeout`` s)."""
        if self._client.service_is_ready():
            return True
        return timeout > 0 and bool(self._client.wait_for_service(timeout_sec=timeout))

    def press(self, hooks: bool = True) -> PanicAnswer:
        """Send the panic request now; never blocks. The answer is reported when it comes.
        ``hooks``: call the ``on_press`` hooks (a tool's running command is interrupted)."""
        answer = self._pressed()
        if self._closed:
            self._settle(answer, False, "the panic line is closed")
        elif self._client.service_is_ready():
            self._send(answer)
        else:  # not discovered (yet): wait for it away from the caller
            threading.Thread(target=self._send_when_ready, args=(answer,), daemon=True).start()
        if hooks:
            self._run_hooks()
        return answer

    def _pressed(self) -> PanicAnswer:
        answer = PanicAnswer()
        with self._lock:
            self.presses += 1
            self.last_press = answer.pressed_at
        return answer

    def _run_hooks(self) -> None:
        for hook in list(self.on_press):
            hook()

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
            with self._client.handle:
                sequence = int(self._client.handle.send_request(Trigger.Request()))
        except Exception as exc:  # the context is gone
            self._settle(answer, False, f"cannot send: {exc}")
            return
        self._expect(sequence, answer)

    def _expect(self, sequence: int, answer: PanicAnswer) -> None:
        with self._lock:
            early = self._early.pop(sequence, None)
            if early is None:
                self._pending[sequence] = answer
        if early is not None:
            self._settle(answer, *early)
            return
        timer = threading.Timer(self.answer_timeout, self._late, args=(sequence, answer))
        timer.daemon = True
        timer.start()

    # ------------------------------------------------------------------ the native key reader
    def watch_terminal(self, terminal: int) -> int | None:
        """Start the native key reader on ``terminal`` (in raw mode). It passes every byte on
        to a pipe whose read end this returns (the caller reads and closes it; it reads the end
        of input once the reader stops). None when the reader cannot start (then the caller
        reads the terminal itself)."""
        from ether_ros import _native
        from ether_ros.ros.native_commands import CommandPathError, loaded_library

        keys_r, keys_w = os.pipe()
        # Room for a whole refused paste, so the reader never has to drop a line end that
        # follows one while the reader of the pipe is still busy with it.
        with contextlib.suppress(OSError):
            fcntl.fcntl(keys_w, fcntl.F_SETPIPE_SZ, KEYS_PIPE_BYTES)
        try:
            self._keys = _native.PanicKeys(
                librcl=loaded_library("librcl"),
                librcutils=loaded_library("librcutils"),
                node=self._node.handle.pointer,
                client=self._client.handle.pointer,
                terminal=terminal,
                forward=keys_w,  # the reader's from now on
                priority=KEY_READER_PRIORITY,
            )
        except (RuntimeError, CommandPathError):
            os.close(keys_r)
            os.close(keys_w)
            return None
        return keys_r

    def scheduling(self) -> str:
        """How the native key reader runs ("" when there is none)."""
        keys = self._keys
        return str(keys.scheduling()) if keys is not None else ""

    def claim_keys(self) -> list[PanicAnswer]:
        """The requests the native key reader sent since the last call (a key that it could not
        send for is sent from here instead); the ``on_press`` hooks run once if there were any."""
        keys = self._keys
        if keys is None:
            return []
        answers = []
        for sequence, read_ns, sent_ns, why in keys.take_sent():
            answer = self._pressed()
            if sequence is not None:
                self._trace(read_ns, sent_ns)
                self._expect(int(sequence), answer)
            elif self._closed:
                self._settle(answer, False, why)
            else:  # not sent natively (the service not discovered, an rcl error): from here
                threading.Thread(target=self._send_when_ready, args=(answer,), daemon=True).start()
            answers.append(answer)
        if answers:
            self._run_hooks()
        return answers

    def _trace(self, read_ns: int, sent_ns: int) -> None:
        """With ``ETHER_ROS_PANIC_TRACE=FILE``, note when the native reader got each panic key
        and sent its request (CLOCK_MONOTONIC ns, one pair per line): the benchmark splits key
        -> wire with them."""
        path = os.environ.get("ETHER_ROS_PANIC_TRACE")
        if path:
            with contextlib.suppress(OSError), open(path, "a") as f:
                f.write(f"{read_ns} {sent_ns}\n")

    @property
    def watching(self) -> bool:
        return self._keys is not None

    def stop_watching(self) -> None:
        """Stop the native key reader (it closes its pipe; idempotent)."""
        keys, self._keys = self._keys, None
        if keys is not None:
            keys.stop()

    # ------------------------------------------------------------------ answers
    def _take_answers(self) -> None:
        try:
            wait_set = _rclpy.WaitSet(0, 0, 0, 1, 0, 0, self._node.context.handle)
        except Exception:  # the context is gone
            return
        while not self._stop.is_set():
            try:
                with self._client.handle:
                    wait_set.clear_entities()
                    wait_set.add_client(self._client.handle)
                    wait_set.wait(_WAIT_NS)
                    while True:
                        header, response = self._client.handle.take_response(Trigger.Response)
                        if header is None:
                            break
                        self._answered(
                            int(header.request_id.sequence_number),
                            bool(response.success),
                            str(response.message),
                        )
            except Exception:  # the client or its context is being destroyed
                if self._stop.is_set() or not self._node.context.ok():
                    return
                time.sleep(0.05)

    def _answered(self, sequence: int, ok: bool, message: str) -> None:
        with self._lock:
            answer = self._pending.pop(sequence, None)
            if answer is None:
                self._early[sequence] = (ok, message)
                return
        self._settle(answer, ok, message, late=answer.done)

    def _late(self, sequence: int, answer: PanicAnswer) -> None:
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
        self.stop_watching()
        self._stop.set()
        self._thread.join(timeout=2)
        with contextlib.suppress(Exception):
            self._node.destroy_node()
