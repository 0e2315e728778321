"""actionlib's server bookkeeping without a network: ids, cancel rules, stored cancels, the status window."""

from __future__ import annotations

from mrosd.actions.status import CANCELED_BY_STAMP, GoalIdGenerator, Status, StatusList, cancel_matches
from mrosd.msg import Time


def test_goal_ids_are_name_count_and_stamp_as_actionlib_makes_them() -> None:
    ids = GoalIdGenerator("/client")
    assert ids.next(Time(12, 5)) == ("/client-1-12.5", Time(12, 5))
    assert ids.next(Time(12, 600)) == ("/client-2-12.600", Time(12, 600))


def test_cancel_matches_all_by_id_and_everything_at_or_before_a_stamp() -> None:
    assert cancel_matches("", Time(), "g", Time(5, 0))
    assert cancel_matches("g", Time(), "g", Time(5, 0))
    assert not cancel_matches("h", Time(), "g", Time(5, 0))
    assert cancel_matches("", Time(5, 0), "g", Time(5, 0))
    assert not cancel_matches("", Time(4, 999), "g", Time(5, 0))


def test_a_cancel_before_its_goal_recalls_the_goal_when_it_arrives() -> None:
    table = StatusList()
    assert table.cancel_received("late", Time(), clock=0.0) == []
    entry, transition = table.goal_received("late", Time(1, 0), Time(2, 0))
    assert entry is None and transition is not None
    assert transition.entry.status is Status.RECALLED and transition.result


def test_a_goal_stamped_before_the_last_cancel_by_stamp_is_recalled_at_once() -> None:
    table = StatusList()
    table.cancel_received("", Time(10, 0), clock=0.0)
    entry, transition = table.goal_received("old", Time(9, 0), Time(11, 0))
    assert entry is None and transition is not None
    assert (transition.entry.status, transition.entry.text) == (Status.RECALLED, CANCELED_BY_STAMP)
    entry, transition = table.goal_received("new", Time(10, 1), Time(11, 0))
    assert entry is not None and transition is None


def test_transitions_follow_actionlib_and_finished_goals_leave_after_the_timeout() -> None:
    table = StatusList(timeout=5.0)
    entry, _ = table.goal_received("g", Time(), Time(3, 0))
    assert entry is not None and entry.stamp == Time(3, 0)  # a zero stamp becomes the arrival time
    table.accept(entry)
    [transition] = table.cancel_received("g", Time(), clock=1.0)
    assert transition.cancel and entry.status is Status.PREEMPTING
    assert table.finish(entry, Status.PREEMPTED, "", clock=2.0) and entry.status is Status.PREEMPTED
    assert not table.finish(entry, Status.SUCCEEDED, "", clock=2.0)  # terminal stays terminal
    table.prune(6.9)
    assert [e.goal_id for e in table] == ["g"]
    table.prune(7.1)
    assert list(table) == []


def test_a_duplicate_goal_id_is_never_run_twice() -> None:
    table = StatusList()
    table.goal_received("g", Time(1, 0), Time(1, 0))
    assert table.goal_received("g", Time(1, 0), Time(1, 0)) == (None, None)


def test_the_status_list_is_bounded_against_a_peer_sending_endless_ids() -> None:
    table = StatusList(max_entries=3)
    for i in range(3):
        table.goal_received(f"g{i}", Time(1, 0), Time(1, 0))
    entry, transition = table.goal_received("g9", Time(1, 0), Time(1, 0))
    assert entry is None and transition is not None and transition.entry.status is Status.REJECTED
    for i in range(10):
        table.cancel_received(f"c{i}", Time(), clock=0.0)
    assert len(table.entries) == 3
