"""`robobpp serve | db upgrade | worker` refuse bad settings in one line, without a traceback or a secret."""

import os
import subprocess
import sys

import pytest

SECRET = "a-long-admin-token-that-must-not-leak"


@pytest.mark.parametrize("command", [["serve", "--port", "1"], ["db", "upgrade"], ["worker"]])
def test_invalid_settings_are_one_clear_line(tmp_path, command):
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")}
    env.update(
        ROBOBPP_ENV="prod",
        ROBOBPP_ADMIN_TOKEN=SECRET,
        ROBOBPP_ALLOW_PRIVATE_POLICY_URLS="true",
        ROBOBPP_STATE_DIR=str(tmp_path),
        ROBOBPP_BROKER_URL="redis://127.0.0.1:1/0",
    )
    proc = subprocess.run(
        [sys.executable, "-m", "robobpp.cli", *command],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert "invalid settings" in proc.stderr and "ROBOBPP_ALLOW_PRIVATE_POLICY_URLS" in proc.stderr
    assert "Traceback" not in proc.stderr and SECRET not in proc.stderr + proc.stdout
