"""odolab/io/owned.py: owned paths never pass a link, a file for a folder, or leave their root."""

from __future__ import annotations

import pytest

from odolab.io.owned import UnsafeOutputError, check_owned_folder, check_owned_path, owned_path, remove_owned
from tests.helpers import outside_folder


def test_owned_paths_never_pass_a_link_a_file_for_a_folder_or_leave_the_root(tmp_path):
    outside = outside_folder(tmp_path)
    root = tmp_path / "out"
    root.mkdir()
    (root / "sub").symlink_to(outside)
    (root / "file").write_text("x")
    (root / "link.tum").symlink_to(outside / "victim.tum")
    for rel, expected, found in (
        ("sub/victim.tum", "expected a folder", "found a symbolic link to"),
        ("file/a.tum", "expected a folder", "found a file"),
        ("link.tum", "expected a regular file or nothing", "found a symbolic link to"),
    ):
        with pytest.raises(UnsafeOutputError, match=f"{expected}, {found}"):
            owned_path(root, rel)
        assert not remove_owned(root, rel)
    for rel in ("../outside/victim.tum", "a/../../outside/victim.tum", str(outside / "victim.tum"), ""):
        with pytest.raises(UnsafeOutputError):
            check_owned_path(root, rel)
    assert (outside / "victim.tum").read_text() == "precious" and sorted(p.name for p in outside.iterdir()) == [
        "victim.tum"
    ]
    assert owned_path(root, "new/deep/a.tum") == root / "new" / "deep" / "a.tum" and (root / "new" / "deep").is_dir()
    for rel, found in (("sub", "a symbolic link to"), ("file", "a file"), ("sub/x", "a symbolic link to")):
        with pytest.raises(UnsafeOutputError, match=f"expected a folder, found {found}"):
            check_owned_folder(root, rel)
    assert check_owned_folder(root, "new/deep") == root / "new" / "deep"
    with pytest.raises(UnsafeOutputError, match=r"found a path that cannot be read \(file name too long\)"):
        check_owned_path(root, "new/" + "x" * 300 + "/a.tum")  # an error line, not an OSError traceback
