"""A port's native answers kept on disk (``backends.native_worker.cached_answers``, used by both ports' reset
caches): asked once per missing key, read back in the caller's order, and a writer killed mid-file leaves
nothing that reads as an answer."""

from simseam.backends.native_worker import cached_answers


def test_missing_keys_are_asked_once_and_answers_come_back_in_order(tmp_path):
    asked = []

    def ask(keys):
        asked.append(list(keys))
        return [{"key": k, "state": [k] * 3} for k in keys]

    first = cached_answers(tmp_path / "resets", [3, 1, 3], ask)
    assert [a["key"] for a in first] == [3, 1, 3] and asked == [[1, 3]]
    again = cached_answers(tmp_path / "resets", [1, 2, 3], ask)
    assert [a["key"] for a in again] == [1, 2, 3] and asked == [[1, 3], [2]]  # only the new key
    assert sorted(p.name for p in (tmp_path / "resets").iterdir()) == ["1.pkl", "2.pkl", "3.pkl"]


def test_a_partial_file_from_a_killed_writer_is_asked_again(tmp_path):
    folder = tmp_path / "resets"
    folder.mkdir()
    leftover = folder / ".5.pkl.k1ll3d.partial"  # what a kill between write and rename leaves (simseam.files)
    leftover.write_bytes(b"\x80\x04 truncated")
    got = cached_answers(folder, [5], lambda keys: [f"answer {k}" for k in keys])
    assert got == ["answer 5"] and (folder / "5.pkl").is_file()
    assert cached_answers(folder, [5], lambda keys: ["asked again"]) == ["answer 5"]  # the kept answer is read


def test_held_answers_are_taken_once_per_interpreter_and_the_oldest_go_first():
    """``HeldAnswers``: a full answer read again soon (a task's ``describe``: its description, then its model's
    build), taken once, by the worker's interpreter and key; at most ``limit`` held, the oldest dropped."""
    from types import SimpleNamespace

    from simseam.backends.native_worker import HeldAnswers

    a, b = SimpleNamespace(python="/venv-a/bin/python"), SimpleNamespace(python="/venv-b/bin/python")
    held = HeldAnswers(limit=2)
    held.hold(a, "reach", {"xml": "a"})
    assert held.take(b, "reach") is None  # another interpreter's answer is not this one's
    assert held.take(a, "reach") == {"xml": "a"} and held.take(a, "reach") is None  # taken once
    for task in ("t1", "t2", "t3"):
        held.hold(a, task, task)
    assert [held.take(a, t) for t in ("t1", "t2", "t3")] == [None, "t2", "t3"]
