"""The dataset directory locks: the write lock names its holder, and a lock file that names none (empty, as
between a writer creating and filling it, or garbage) is no error."""

import os

import pytest

from d5rl.datasets.lock import WRITE_LOCK, _writer, writing


@pytest.mark.parametrize("content", ["", "\n", "not-a-pid\n"])
def test_a_write_lock_file_that_names_no_pid_is_taken_without_error(tmp_path, content):
    (tmp_path / WRITE_LOCK).write_text(content)
    assert _writer(tmp_path) is None
    with writing(tmp_path):
        assert _writer(tmp_path) is not None  # the holder writes its pid


def test_the_write_lock_names_its_holder(tmp_path):
    assert _writer(tmp_path) is None  # no file yet
    with writing(tmp_path):
        assert _writer(tmp_path) == os.getpid()
