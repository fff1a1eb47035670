"""The refusal answers the node's Python side publishes: bounded per publisher and in all, so that
many flooding publishers cannot crowd a client's own answer out of the shared results topic
(the Rust threads' budgets are tested in crates/commands/src/receiver.rs)."""

from __future__ import annotations

from ether_ros import _native
from ether_ros.ros.native_commands import RefusalBudget

PER_PUBLISHER = _native.CommandReceiver.REFUSAL_ANSWERS_PER_S
TOTAL = _native.CommandReceiver.REFUSAL_ANSWERS_TOTAL_PER_S


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_each_publisher_has_a_burst_of_its_own() -> None:
    budget = RefusalBudget(Clock())
    answered = sum(budget.spend(b"a") for _ in range(3 * PER_PUBLISHER))
    assert answered == PER_PUBLISHER
    assert budget.spend(b"b"), "another publisher's budget is its own"
    assert budget.unanswered == 2 * PER_PUBLISHER


def test_many_publishers_together_get_at_most_the_total() -> None:
    assert TOTAL > PER_PUBLISHER  # a few flooders do not reach it; many do
    clock = Clock()
    budget = RefusalBudget(clock)
    publishers = [bytes([n]) for n in range(2 * TOTAL // PER_PUBLISHER + 1)]
    answered = sum(budget.spend(p) for p in publishers for _ in range(PER_PUBLISHER))
    assert answered == TOTAL
    clock.now += 1.0  # one second refills the total, and each publisher's own
    answered = sum(budget.spend(p) for p in publishers for _ in range(PER_PUBLISHER))
    assert answered == TOTAL


def test_a_request_of_no_known_publisher_is_always_answered() -> None:
    budget = RefusalBudget(Clock())
    assert all(budget.spend(None) for _ in range(10 * TOTAL))
