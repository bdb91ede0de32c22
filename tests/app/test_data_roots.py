"""Nothing outside the data roots is read: links of any number of hops, hard links, links swapped
in after registration, the sensor file of a config (app/data_roots.py)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from app.core.errors import Forbidden
from app.data_roots import DataRoots, GuardedSource


def _register(client, factory, path, **body):
    admin = factory.user("admin")
    return client.post("/api/v1/datasets", json={"path": str(path), "ingest": False, **body}, headers=admin.headers)


def _secret(tmp_path: Path) -> Path:
    outside = tmp_path / "outside"
    outside.mkdir(exist_ok=True)
    secret = outside / "secret.bin"
    secret.write_bytes(b"\1" * 16)
    return secret


def test_data_roots_two_hop_link_out_of_the_roots_is_403(client, factory, settings, tmp_path):
    """seq/velodyne -> other (inside), other/000001.bin -> a file outside: refused at registration."""
    root = settings.data_roots[0]
    seq, other = root / "seq", root / "other"
    seq.mkdir()
    other.mkdir()
    (other / "000000.bin").write_bytes(b"\0" * 16)
    os.symlink(_secret(tmp_path), other / "000001.bin")
    os.symlink(other, seq / "velodyne")
    r = _register(client, factory, seq)
    assert r.status_code == 403 and "velodyne/000001.bin" in r.json()["detail"], r.text
    assert "secret" not in r.text


def test_data_roots_hard_link_to_an_outside_file_is_403(client, factory, settings, tmp_path):
    folder = factory.sequence_folder("seq")
    os.link(_secret(tmp_path), folder / "velodyne" / "000001.bin")
    r = _register(client, factory, folder)
    assert r.status_code == 403 and "hard link" in r.json()["detail"], r.text


def test_data_roots_hard_links_inside_the_roots_are_fine(client, factory, settings):
    folder = factory.sequence_folder("seq")
    other = factory.sequence_folder("other")
    os.link(folder / "velodyne" / "000000.bin", folder / "velodyne" / "000001.bin")  # twice in the sequence
    os.link(other / "velodyne" / "000000.bin", folder / "velodyne" / "000002.bin")  # shared with another one
    assert _register(client, factory, folder).status_code == 201


def test_data_roots_link_loop_ends(client, factory, settings):
    folder = factory.sequence_folder("seq")
    os.symlink(folder, folder / "velodyne" / "again")
    assert _register(client, factory, folder).status_code == 201


def test_data_roots_sensor_file_outside_is_403(client, factory, tmp_path):
    folder = factory.sequence_folder("seq")
    meta = tmp_path / "outside" / "os1.json"
    meta.parent.mkdir(exist_ok=True)
    meta.write_text("{}")
    r = _register(client, factory, folder, config={"sensor": {"name": str(meta)}})
    assert r.status_code == 403 and "sensor file" in r.json()["detail"], r.text
    assert _register(client, factory, folder, config={"sensor": {"name": "hdl64e"}}).status_code == 201


@pytest.mark.parametrize("path", ["seq/" + "x" * 256, "seq\x00/x"])
def test_data_roots_long_part_or_nul_byte_is_422(client, factory, path):
    assert _register(client, factory, path).status_code == 422


class _Source:
    def __init__(self, files: list[Path]) -> None:
        self._files, self.path = files, files[0].parent

    def __len__(self) -> int:
        return len(self._files)

    def frame(self, index: int) -> bytes:
        return self._files[index].read_bytes()


def test_data_roots_link_swapped_in_after_the_check_is_refused_at_read(tmp_path):
    root = tmp_path / "root"
    (root / "seq").mkdir(parents=True)
    files = [root / "seq" / f"{i}.bin" for i in range(2)]
    for f in files:
        f.write_bytes(b"\0")
    roots = DataRoots.of([root])
    roots.check_tree(root / "seq")
    source = GuardedSource(_Source(files), roots)
    assert source.frame(1) == b"\0"
    files[1].unlink()
    os.symlink(_secret(tmp_path), files[1])
    with pytest.raises(Forbidden, match="1.bin"):
        source.frame(1)
    files[1].unlink()
    os.link(_secret(tmp_path), files[1])  # a hard link the check never saw
    with pytest.raises(Forbidden, match="hard link"):
        source.frame(1)
