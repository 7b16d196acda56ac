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
