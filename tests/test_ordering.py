"""Newest wins per sender, with marks that expire: no sequence number freezes a sender for longer."""

from __future__ import annotations

import pytest

from sync.ordering import MARK_EXPIRY, Marks


def test_newer_messages_are_taken_and_older_ones_refused_while_the_mark_lasts():
    marks = Marks()
    assert marks.newer("d", 1, 5, now=0.0)
    marks.take("d", 1, 5, now=0.0)
    assert not marks.newer("d", 1, 5, now=0.1)  # the same one again
    assert not marks.newer("d", 1, 4, now=0.1)
    assert not marks.newer("d", 0, 99, now=0.1)  # an older epoch
    assert marks.newer("d", 1, 6, now=0.1) and marks.newer("d", 2, 0, now=0.1)
    assert marks.newer("other", 0, 0, now=0.1)  # each sender has its own mark


def test_a_forged_mark_holds_its_sender_back_for_at_most_the_expiry():
    marks = Marks()
    largest = 2**63 - 1
    marks.take("d", largest, largest, now=10.0)
    # The real driver (restarted: a smaller epoch) keeps sending; none is taken, so the mark is not renewed.
    assert not marks.newer("d", 3, 1, now=10.0 + MARK_EXPIRY - 1e-3)
    assert marks.newer("d", 3, 2, now=10.0 + MARK_EXPIRY)
    marks.take("d", 3, 2, now=10.0 + MARK_EXPIRY)
    assert not marks.newer("d", 3, 1, now=10.0 + MARK_EXPIRY)  # from then on, ordered again


def test_past_its_capacity_the_least_recent_sender_is_forgotten():
    marks = Marks(capacity=3)
    evicted = [marks.take(f"d{k}", 1, 1, now=k / 10) for k in range(3)]
    marks.take("d0", 1, 2, now=0.3)  # taken again: now the most recent
    evicted.append(marks.take("d3", 1, 1, now=0.4))
    assert evicted == [False, False, False, True] and len(marks) == 3
    assert marks.newer("d1", 0, 0, now=0.4)  # forgotten
    assert not marks.newer("d0", 1, 2, now=0.4)  # kept


@pytest.mark.parametrize(("expiry", "capacity"), [(0.0, 3), (float("nan"), 3), (1.0, 0)])
def test_marks_that_could_never_hold_are_refused(expiry, capacity):
    with pytest.raises(ValueError, match="expiry must be > 0 s and capacity >= 1"):
        Marks(expiry=expiry, capacity=capacity)
