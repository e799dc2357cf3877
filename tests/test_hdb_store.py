"""The server's content store (server/hdb/store.py): contents by SHA-256, bounded, least recently
used out, checked when they enter and when they are read back."""

from __future__ import annotations

import hashlib
import os
import time

import pytest

from hydrolink.server.hdb.store import ContentStore, default_folder


def blob(i: int, size: int = 1000) -> bytes:
    return bytes([i % 256]) * size


def test_put_get_and_the_disk_tier(tmp_path):
    store = ContentStore(tmp_path, memory_bytes=0)          # every read goes to disk
    digest, new = store.put(blob(1))
    assert digest == hashlib.sha256(blob(1)).hexdigest() and new
    assert store.put(blob(1)) == (digest, False)
    assert store.get(digest) == blob(1)
    assert [p.name for p in tmp_path.iterdir()] == [digest]  # named by its hash and nothing else
    assert store.missing([digest, "0" * 64, "0" * 64]) == ["0" * 64]
    assert store.get("0" * 64) is None


def test_a_wrong_hash_is_refused(tmp_path):
    store = ContentStore(tmp_path)
    with pytest.raises(ValueError, match="not " + "1" * 64):
        store.put(blob(2), "1" * 64)
    assert list(tmp_path.iterdir()) == []


def test_least_recently_used_leave_first(tmp_path):
    store = ContentStore(tmp_path, disk_bytes=3500, memory_bytes=0)
    digests = []
    for i in range(3):
        digests.append(store.put(blob(i))[0])
        past = time.time() - 100 + i                             # distinct ages, oldest first
        os.utime(tmp_path / digests[-1], (past, past))
    store.get(digests[0])                                        # used again: now the newest
    digests.append(store.put(blob(3))[0])                        # over 3500 bytes: the oldest goes
    assert not store.has(digests[1])
    assert all(store.has(d) for d in (digests[0], digests[2], digests[3]))
    with pytest.raises(ValueError, match="over the store's bound"):
        store.put(blob(9, 4000))


def test_a_damaged_disk_entry_counts_as_absent(tmp_path):
    digest, _ = ContentStore(tmp_path).put(blob(5))
    (tmp_path / digest).write_bytes(b"bit rot")
    assert ContentStore(tmp_path).get(digest) is None
    assert not (tmp_path / digest).exists()


def test_memory_only_store_is_bounded():
    store = ContentStore(None, memory_bytes=2500)
    a, _ = store.put(blob(1))
    b, _ = store.put(blob(2))
    c, _ = store.put(blob(3))
    assert not store.has(a) and store.has(b) and store.has(c)


def test_default_folder_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("HYDROLINK_HDB_STORE", str(tmp_path / "a"))
    assert default_folder() == tmp_path / "a"
    monkeypatch.delenv("HYDROLINK_HDB_STORE")
    monkeypatch.setenv("HYDROLINK_CACHE", str(tmp_path / "c"))
    assert default_folder() == tmp_path / "c" / "hdb_store"
