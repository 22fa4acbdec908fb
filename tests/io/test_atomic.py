"""`exclusive_folder`: one process at a time, and nothing left of a failed block."""
import pytest

from probvis import ProbvisError
from probvis.io import atomic


@pytest.mark.parametrize("locking", [True, False])
def test_a_failed_block_leaves_no_folder_it_made_and_stale_temporaries_go_only_where_locked(tmp_path, monkeypatch,
                                                                                            locking):
    """Folders made for the block go again when it fails, with or without a lock (NFS); the temporaries a killed
    writer left are removed only under the lock (unlocked, another writer's may be live)."""
    if not locking:
        monkeypatch.setattr(atomic, "fcntl", None)
    out = tmp_path / "a" / "b"
    with pytest.raises(RuntimeError):
        with atomic.exclusive_folder(out, "report folder"):
            assert out.is_dir()
            raise RuntimeError
    assert not (tmp_path / "a").exists()
    out.mkdir(parents=True)
    (out / ".pv-abcd1234.png").write_bytes(b"half")
    with atomic.exclusive_folder(out, "report folder"):
        pass
    assert (out / ".pv-abcd1234.png").exists() != locking


def test_a_held_folder_is_refused_and_left_as_it_is(tmp_path):
    out = tmp_path / "r"
    with atomic.exclusive_folder(out, "report folder"):
        with pytest.raises(ProbvisError, match="report folder '.*r' is being written by another probvis process"):
            with atomic.exclusive_folder(out, "report folder"):
                pass
        assert out.is_dir()
