"""VectorEnv._replies: the workers' replies read as they ring the bell, returned in the order of the slots
(no processes: pipes stand in for the workers, the bell and their sentinels)."""

from __future__ import annotations

import multiprocessing as mp
import os
import select

from simseam.runner.vector import VectorEnv, _rings, _Slot


class _Proc:
    def __init__(self, alive: bool = True):
        self.alive = alive

    def is_alive(self) -> bool:
        return self.alive


def _slot(env: int):
    parent, child = mp.Pipe()
    r, w = os.pipe()  # the sentinel: readable once the "process" has ended (its write end closed)
    s = _Slot(env=env, proc=_Proc(), conn=parent)
    s.fd, s.sentinel = parent.fileno(), r
    return s, child, w


def _vec(slots):
    """A VectorEnv's bell and poll over ``slots`` (as ``__init__`` and ``_spawn`` set them up)."""
    vec = VectorEnv.__new__(VectorEnv)
    vec.spin_us = 0
    vec._bell_r, vec._bell_w = mp.Pipe(duplex=False)
    vec._bell = vec._bell_r.fileno()
    os.set_blocking(vec._bell, False)
    vec._poll = select.poll()
    vec._poll.register(vec._bell, select.POLLIN)
    vec._sentinels, vec._dead = {}, set()
    for s in slots:
        vec._poll.register(s.sentinel, select.POLLIN)
        vec._sentinels[s.sentinel] = [s]
    return vec


def _answer(vec, child, env: int, msg) -> None:
    """What a worker does with a reset's or a step's reply that goes through its pipe."""
    os.write(vec._bell_w.fileno(), _rings(env)[0])
    child.send(msg)


def test_replies_in_slot_order_whatever_order_they_arrive():
    slots, children, ends = zip(*[_slot(j) for j in range(4)])
    vec = _vec(slots)
    try:
        for j in (3, 1, 0, 2):  # out of order
            _answer(vec, children[j], j, ("obs", {"j": j}, (float(j), False, False, {}), None, None))
        out = vec._replies(list(slots))
        assert [m[1]["j"] for m in out] == [0, 1, 2, 3]
        assert [m[2][0] for m in out] == [0.0, 1.0, 2.0, 3.0]
        # a subset, in the order asked
        _answer(vec, children[2], 2, ("obs", {"j": 2}, None, None, None))
        _answer(vec, children[0], 0, ("obs", {"j": 0}, None, None, None))
        assert [m[1]["j"] for m in vec._replies([slots[2], slots[0]])] == [2, 0]
    finally:
        for s, c, w in zip(slots, children, ends):
            s.conn.close(), c.close(), os.close(s.sentinel), os.close(w)


def test_a_dead_worker_answers_none_and_the_others_answer_whole():
    slots, children, ends = zip(*[_slot(j) for j in range(3)])
    vec = _vec(slots)
    try:
        _answer(vec, children[0], 0, ("obs", {"j": 0}, None, None, None))
        _answer(vec, children[2], 2, ("obs", {"j": 2}, None, None, None))
        slots[1].proc.alive = False  # worker 1 died: its sentinel readable
        children[1].close()
        os.close(ends[1])
        out = vec._replies(list(slots))
        assert out[0][1] == {"j": 0} and out[1] is None and out[2][1] == {"j": 2}
    finally:
        for j, (s, c, w) in enumerate(zip(slots, children, ends)):
            s.conn.close(), os.close(s.sentinel)
            if j != 1:
                c.close(), os.close(w)


def test_a_reply_rung_for_before_the_worker_died_is_read():
    slots, children, ends = zip(*[_slot(j) for j in range(2)])
    vec = _vec(slots)
    try:
        _answer(vec, children[1], 1, ("obs", {"j": 1}, None, None, None))
        os.close(ends[1])  # then it ended
        _answer(vec, children[0], 0, ("obs", {"j": 0}, None, None, None))
        out = vec._replies(list(slots))
        assert out[0][1] == {"j": 0} and out[1][1] == {"j": 1}
    finally:
        for j, (s, c, w) in enumerate(zip(slots, children, ends)):
            s.conn.close(), c.close(), os.close(s.sentinel)
            if j != 1:
                os.close(w)


def test_a_worker_that_died_while_nothing_was_asked_is_found_at_its_next_command():
    slots, children, ends = zip(*[_slot(j) for j in range(2)])
    vec = _vec(slots)
    try:
        os.close(ends[1])  # worker 1 ended while only worker 0 is asked
        _answer(vec, children[0], 0, ("obs", {"j": 0}, None, None, None))
        assert vec._replies([slots[0]])[0][1] == {"j": 0}
        assert vec._dead == {1} and slots[1].sentinel not in vec._sentinels
        assert vec._replies([slots[1]]) == [None]
    finally:
        for j, (s, c, w) in enumerate(zip(slots, children, ends)):
            s.conn.close(), c.close(), os.close(s.sentinel)
            if j != 1:
                os.close(w)
