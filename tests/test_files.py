"""Files that appear whole or not at all (``simseam.files``): the ports' disk caches, run files and the results
page are written through it. Two writers of one target at once never mix their bytes; a writer that fails leaves
the target as it was and no temporary file."""

import threading

import pytest

from simseam.files import atomic_path, write_atomic


def test_write_atomic_writes_bytes_and_text_with_the_mode(tmp_path):
    write_atomic(tmp_path / "a.bin", b"\x00\x01")
    write_atomic(tmp_path / "b.txt", "héllo", mode=0o600)
    assert (tmp_path / "a.bin").read_bytes() == b"\x00\x01" and (tmp_path / "b.txt").read_text() == "héllo"
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o644
    assert (tmp_path / "b.txt").stat().st_mode & 0o777 == 0o600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "b.txt"]


def test_a_failed_writer_leaves_the_target_as_it_was_and_no_temporary(tmp_path):
    target = tmp_path / "model.mjb"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="compile failed"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("compile failed")
    assert target.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["model.mjb"]


def test_two_writers_of_one_target_get_their_own_temporaries(tmp_path):
    target = tmp_path / "3.pkl"
    with atomic_path(target) as first, atomic_path(target) as second:
        assert first != second and first.parent == second.parent == tmp_path
        first.write_bytes(b"first")
        second.write_bytes(b"second")
    assert target.read_bytes() == b"first"  # the outer block renames last
    assert [p.name for p in tmp_path.iterdir()] == ["3.pkl"]


def test_concurrent_writers_never_leave_a_mixed_file(tmp_path):
    """Four threads write one key 25 times each, 2 MB of their own byte: every read of the target is one
    writer's whole payload (with one shared temporary name, the writes interleave, or a rename finds its
    temporary gone)."""
    target, size, errors, seen = tmp_path / "key.pkl", 2_000_000, [], set()

    def writer(byte: int) -> None:
        try:
            for _ in range(25):
                write_atomic(target, bytes([byte]) * size)
        except Exception as exc:  # noqa: BLE001 - recorded for the assertion below
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(b,)) for b in (1, 2, 3, 4)]
    for t in threads:
        t.start()
    while any(t.is_alive() for t in threads):
        if target.exists():
            data = target.read_bytes()
            assert len(data) == size and data.count(data[:1]) == size, "a mixed or short file was read"
            seen.add(data[0])
    for t in threads:
        t.join()
    assert not errors and target.stat().st_size == size
    assert [p.name for p in tmp_path.iterdir()] == ["key.pkl"]
