"""Report freshness (ether_ros.ros.freshness): stale after two periods, never before a floor."""

from __future__ import annotations

from ether_ros.ros.freshness import DEFAULT_PERIOD_S, MIN_STALE_S, Arrivals, describe_age


def test_a_report_is_stale_after_two_of_its_periods() -> None:
    a = Arrivals()
    assert not a.fresh("diagnostics", now=0.0)  # nothing arrived yet
    a.note("diagnostics", now=10.0)
    assert a.period("diagnostics") == DEFAULT_PERIOD_S  # one report: the default period
    a.note("diagnostics", now=13.0)  # a node reporting every 3 s
    assert a.period("diagnostics") == 3.0
    assert a.fresh("diagnostics", now=18.9)
    assert not a.fresh("diagnostics", now=19.1)
    assert a.age("diagnostics", now=19.0) == 6.0


def test_one_late_report_does_not_change_the_period() -> None:
    a = Arrivals()
    for t in (0.0, 1.0, 2.0, 3.4, 4.0):  # every second, one of them 0.4 s late
        a.note("diagnostics", now=t)
    assert a.period("diagnostics") == 1.0
    assert a.fresh("diagnostics", now=5.9) and not a.fresh("diagnostics", now=6.1)


def test_a_fast_stream_is_not_stale_within_the_floor() -> None:
    a = Arrivals()
    a.note("inputs/leg", now=1.000)
    a.note("inputs/leg", now=1.004)  # every 4 ms
    assert a.stale_after("inputs/leg") == MIN_STALE_S
    assert a.fresh("inputs/leg", now=1.004 + MIN_STALE_S - 0.01)
    assert not a.fresh("inputs/leg", now=1.004 + MIN_STALE_S + 0.01)


def test_ages_read_well() -> None:
    assert describe_age(0.42) == "0.4 s"
    assert describe_age(42) == "42 s"
    assert describe_age(600) == "10 min"
