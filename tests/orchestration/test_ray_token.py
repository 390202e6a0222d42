"""compare warns when Ray's token file, which keeps others out of a local sweep, is readable by them."""

from __future__ import annotations

import os

import pytest

from containergym_marl.orchestration.cluster import token_exposure


@pytest.mark.parametrize("file_mode, folder_mode, who", [
    (0o644, 0o755, "its group and other users"),  # Ray's own default
    (0o604, 0o701, "other users"),
    (0o640, 0o750, "its group"),
    (0o600, 0o755, None),
    (0o644, 0o700, None),  # readable, but nobody else can enter the folder
])
def test_token_exposure(tmp_path, file_mode, folder_mode, who):
    folder = tmp_path / ".ray"
    folder.mkdir()
    token = folder / "auth_token"
    token.write_text("secret")
    os.chmod(token, file_mode)
    os.chmod(folder, folder_mode)
    try:
        message = token_exposure(token)
    finally:
        os.chmod(folder, 0o700)
    if who is None:
        assert message is None
    else:
        assert f"can be read by {who}" in message and "chmod 600" in message and str(token) in message


def test_no_token_file_is_no_exposure(tmp_path):
    assert token_exposure(tmp_path / "absent" / "auth_token") is None
