"""VectorEnv._replies: the workers' replies read as they arrive, returned in the order of the slots (no
processes: pipes stand in for the workers)."""

from __future__ import annotations

import multiprocessing as mp
import os
import select

from simseam.runner.vector import VectorEnv, _Slot


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
    s.waiter = select.poll()
    s.waiter.register(s.fd, select.POLLIN)
    s.waiter.register(s.sentinel, select.POLLIN)
    return s, child, w


def _vec():
    vec = VectorEnv.__new__(VectorEnv)
    vec.spin_us = 0
    return vec


def test_replies_in_slot_order_whatever_order_they_arrive():
    slots, children, ends = zip(*[_slot(j) for j in range(4)])
    try:
        for j in (3, 1, 0, 2):  # out of order
            children[j].send(("obs", {"j": j}, (float(j), False, False, {}), None, None))
        out = _vec()._replies(list(slots))
        assert [m[1]["j"] for m in out] == [0, 1, 2, 3]
        assert [m[2][0] for m in out] == [0.0, 1.0, 2.0, 3.0]
        # a subset, in the order asked
        children[2].send(("obs", {"j": 2}, None, None, None))
        children[0].send(("obs", {"j": 0}, None, None, None))
        assert [m[1]["j"] for m in _vec()._replies([slots[2], slots[0]])] == [2, 0]
    finally:
        for s, c, w in zip(slots, children, ends):
            s.conn.close(), c.close(), os.close(s.sentinel), os.close(w)


def test_a_dead_worker_answers_none_and_the_others_answer_whole():
    slots, children, ends = zip(*[_slot(j) for j in range(3)])
    try:
        children[0].send(("obs", {"j": 0}, None, None, None))
        children[2].send(("obs", {"j": 2}, None, None, None))
        slots[1].proc.alive = False  # worker 1 died: its pipe closed, its sentinel readable
        children[1].close()
        os.close(ends[1])
        out = _vec()._replies(list(slots))
        assert out[0][1] == {"j": 0} and out[1] is None and out[2][1] == {"j": 2}
    finally:
        for j, (s, c, w) in enumerate(zip(slots, children, ends)):
            s.conn.close(), os.close(s.sentinel)
            if j != 1:
                c.close(), os.close(w)


def test_a_dead_worker_whose_pipe_stays_open_is_found_by_its_sentinel():
    slots, children, ends = zip(*[_slot(j) for j in range(2)])
    try:
        children[0].send(("obs", {"j": 0}, None, None, None))
        slots[1].proc.alive = False
        os.close(ends[1])  # the sentinel only: the pipe's other end is still open somewhere
        out = _vec()._replies(list(slots))
        assert out[0][1] == {"j": 0} and out[1] is None
        assert _vec()._replies([slots[1]]) == [None]  # alone: the one-slot path
    finally:
        for j, (s, c, w) in enumerate(zip(slots, children, ends)):
            s.conn.close(), c.close(), os.close(s.sentinel)
            if j != 1:
                os.close(w)
