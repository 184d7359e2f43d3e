"""The per-run secret of ``radseek run``: every process of the stack connects to the run's router as its own
user, and the router lets each put only its own keys (``radseek.zenoh_auth``).

``OUT/zenoh/credentials`` (mode 0600, in a 0700 folder) holds one random password per user: ``detector@V``,
``vehicle@V`` and ``mission@V`` for each vehicle V, ``recorder`` and ``observer`` (the launcher's own session
and any inspection tool). The stack's processes find it through ``RADSEEK_ZENOH_CREDENTIALS`` in their
environment. ``OUT/zenoh/observer.json5`` is the observer's client configuration for third-party zenoh tools
(``zenoh --config``, ``z_sub -c``) and ``radseek echo --zenoh-config``. The passwords are never printed.
"""

from __future__ import annotations

import json
import os
import secrets
from pathlib import Path

from radseek.zenoh_auth import CREDENTIALS_ENV, PUTS, READER, RECORDER, User, user_name

FOLDER = "zenoh"


def _write_private(path: Path, text: str) -> None:
    """Write a new file readable by its owner only (never an existing one: O_EXCL)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)


def write_run_credentials(out: Path, vehicles: list[str], endpoint: str) -> Path:
    """Generate the run's users and passwords under ``out/zenoh/``; returns the credentials file."""
    folder = out / FOLDER
    folder.mkdir(mode=0o700, parents=True)
    folder.chmod(0o700)  # whatever the umask
    users = [User(user_name(role, v), secrets.token_urlsafe(24)) for v in vehicles for role in PUTS]
    users += [User(name, secrets.token_urlsafe(24)) for name in (RECORDER, READER)]
    path = (folder / "credentials").resolve()
    _write_private(path, "".join(f"{u.name}:{u.password}\n" for u in users))
    observer = next(u for u in users if u.name == READER)
    config = {"mode": "client", "connect": {"endpoints": [endpoint]}, "listen": {"endpoints": []},
              "scouting": {"multicast": {"enabled": False}},
              "transport": {"auth": {"usrpwd": {"user": observer.name, "password": observer.password}}}}
    _write_private(folder / "observer.json5", json.dumps(config, indent=2) + "\n")
    return path


def stack_env(credentials: Path) -> dict[str, str]:
    """The environment every process of the stack gets on top of the launcher's."""
    return {CREDENTIALS_ENV: str(credentials)}
