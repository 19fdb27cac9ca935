import os
import stat

import pytest

from training.core.atomic_write import atomic_open


def test_output_appears_only_when_complete(tmp_path):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_open(target) as f:
            f.write(b"half")
            raise RuntimeError("interrupted")
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]  # no temp file left behind


def test_output_gets_ordinary_permissions(tmp_path):
    umask = os.umask(0o022)
    try:
        with atomic_open(tmp_path / "out.txt", "w") as f:
            f.write("x")
    finally:
        os.umask(umask)
    assert stat.S_IMODE((tmp_path / "out.txt").stat().st_mode) == 0o644


def test_the_file_is_on_the_disk_before_its_name_and_the_rename_after(tmp_path, monkeypatch):
    """atomic_path (checkpoints, projects, .spz, images) flushes the written file before the rename and the folder
    after it, as a crash-safe write needs: before, it renamed without either, and a power cut could leave a
    checkpoint renamed into place but empty."""
    import torch

    from training.reconstruct.checkpoint import save_checkpoint

    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        st = os.fstat(fd)
        events.append(("fsync", "folder" if stat.S_ISDIR(st.st_mode) else st.st_ino))
        real_fsync(fd)

    def replace(src, dst):
        events.append(("rename", os.stat(src).st_ino))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    target = tmp_path / "checkpoint.pt"
    save_checkpoint(target, {"step": 1, "params": torch.zeros(3)})
    inode = target.stat().st_ino
    assert events == [("fsync", inode), ("rename", inode), ("fsync", "folder")]
