"""The per-run secret of ``radseek run``: every process of the stack connects to the run's router as its own
user, and the router lets each put only its own keys (``radseek.zenoh_auth``).

``OUT/zenoh/credentials`` (mode 0600, in a 0700 folder) holds one random password per user: ``detector@V``,
``vehicle@V`` and ``mission@V`` for each vehicle V, ``recorder`` and ``observer`` (the launcher's own session
and any inspection tool). The stack's processes find it through ``RADSEEK_ZENOH_CREDENTIALS`` in their
environment. ``OUT/zenoh/observer.json5`` is the observer's client configuration for third-party zenoh tools
(``zenoh --config``, ``z_sub -c``) and ``radseek echo --zenoh-config``. The passwords are never printed.

The same users serve ``docker/compose.yaml`` (:func:`write_compose_secrets`): there each container is given
only its own line, the router the whole file.
"""

from __future__ import annotations

import json
import os
import secrets
from pathlib import Path

from radseek.zenoh_auth import CREDENTIALS_ENV, PUTS, READER, RECORDER, User, user_name

FOLDER = "zenoh"
#: the compose services that connect as a role of the vehicle, each given only its own credential
COMPOSE_ROLES = tuple(PUTS)


def _write_private(path: Path, text: str, owner: tuple[int, int] | None = None) -> None:
    """Write a new file readable by its owner only (never an existing one: O_EXCL); ``owner`` (uid, gid) is
    given the file before anything is written to it."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with os.fdopen(fd, "w") as fh:
            if owner is not None:
                os.fchown(fd, *owner)
            fh.write(text)
    except OSError:
        path.unlink(missing_ok=True)  # ours: O_EXCL created it
        raise


def new_users(vehicles: list[str]) -> list[User]:
    """One user with a fresh random password per role of each vehicle, and the recorder and the observer."""
    users = [User(user_name(role, v), secrets.token_urlsafe(24)) for v in vehicles for role in PUTS]
    return users + [User(name, secrets.token_urlsafe(24)) for name in (RECORDER, READER)]


def credentials_text(users: list[User]) -> str:
    """zenoh's ``usrpwd`` dictionary: ``USER:PASSWORD`` per line."""
    return "".join(f"{u.name}:{u.password}\n" for u in users)


def observer_config(observer: User, endpoint: str) -> str:
    """A zenoh client configuration (JSON5) that connects to ``endpoint`` as ``observer``."""
    config = {"mode": "client", "connect": {"endpoints": [endpoint]}, "listen": {"endpoints": []},
              "scouting": {"multicast": {"enabled": False}},
              "transport": {"auth": {"usrpwd": {"user": observer.name, "password": observer.password}}}}
    return json.dumps(config, indent=2) + "\n"


def write_run_credentials(out: Path, vehicles: list[str], endpoint: str) -> Path:
    """Generate the run's users and passwords under ``out/zenoh/``; returns the credentials file."""
    folder = out / FOLDER
    folder.mkdir(mode=0o700, parents=True)
    folder.chmod(0o700)  # whatever the umask
    users = new_users(vehicles)
    path = (folder / "credentials").resolve()
    _write_private(path, credentials_text(users))
    _write_private(folder / "observer.json5", observer_config(next(u for u in users if u.name == READER), endpoint))
    return path


def write_compose_secrets(out: Path, vehicle: str, endpoint: str, owner: tuple[int, int] | None = None,
                          host_owner: tuple[int, int] | None = None) -> list[Path]:
    """The credentials of one compose stack in the folder ``out`` (created 0700; it must hold none of them yet):
    ``router.credentials`` (every user), ``ROLE.credentials`` (that role's line only) for each of
    :data:`COMPOSE_ROLES`, all owned by ``owner`` (the image's user, so a container reads its 0600 file), and
    ``observer.credentials`` and ``observer.json5`` (connecting to ``endpoint``) for the host's tools, owned like
    the folder by ``host_owner`` (default: whoever runs this). Returns the files written; on an error none is
    left behind."""
    out.mkdir(mode=0o700, parents=True, exist_ok=True)
    out.chmod(0o700)
    if host_owner is not None:
        os.chown(out, *host_owner)
    users = new_users([vehicle])
    by_name = {u.name: u for u in users}
    observer = by_name[READER]
    files = [("router.credentials", credentials_text(users), owner)]
    files += [(f"{role}.credentials", credentials_text([by_name[user_name(role, vehicle)]]), owner)
              for role in COMPOSE_ROLES]
    files += [("observer.credentials", credentials_text([observer]), host_owner),
              ("observer.json5", observer_config(observer, endpoint), host_owner)]
    for name, _, _ in files:
        if (out / name).exists():
            raise FileExistsError(f"{out / name} already exists: remove {out} (and restart the stack) for new "
                                  "credentials; nothing was written")
    written: list[Path] = []
    try:
        for name, text, who in files:
            path = out / name
            _write_private(path, text, who)
            written.append(path)
    except OSError:
        for path in written:
            path.unlink()
        raise
    return written


def stack_env(credentials: Path) -> dict[str, str]:
    """The environment every process of the stack gets on top of the launcher's."""
    return {CREDENTIALS_ENV: str(credentials)}
