"""The one backoff: pauses double from the first and never pass the longest."""
from itertools import islice

from mesh.backoff import pause_after, pauses


def test_pauses_double_up_to_the_longest_and_go_on():
    assert list(islice(pauses(0.05, 1.0), 8)) == [0.05, 0.1, 0.2, 0.4, 0.8, 1.0, 1.0, 1.0]


def test_the_pause_after_n_failures_is_the_nth_pause():
    assert [pause_after(n, 1.0, 30.0) for n in range(1, 8)] == list(islice(pauses(1.0, 30.0), 7))
    assert pause_after(0, 0.5, 8.0) == 0.5  # no failure yet: the first pause, never less
