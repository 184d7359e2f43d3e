"""Who may put which zenoh keys: the users of an authenticated radseek network and the router's ACL.

A credentials file holds one ``USER:PASSWORD`` per line (zenoh's own ``usrpwd`` dictionary format, which the
router is given as it is: no blank lines, no comments). A user's name says its rights:

- ``ROLE@VEHICLE`` (or ``ROLE.LABEL@VEHICLE``, e.g. ``detector.board7@uav0``: a second identity with the same
  rights) puts that role's keys of that vehicle, ``radseek/VEHICLE/...`` (:data:`PUTS`);
- any other name (``recorder``, ``observer``, ``groundstation``) only reads.

Everyone authenticated may subscribe to everything; nobody else can open a session at all. The file is named
to every radseek process by the environment variable :data:`CREDENTIALS_ENV`: the router builds its
``transport.auth.usrpwd`` and ``access_control`` from it (:func:`access_control`), every other process picks
its own line (:func:`find_user`). ``radseek run`` writes one per run (``launch/zenoh_auth.py``).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from radseek import topics

CREDENTIALS_ENV = "RADSEEK_ZENOH_CREDENTIALS"

#: role -> the topics (relative to radseek/<vehicle>/) its users may put
PUTS: dict[str, tuple[str, ...]] = {
    "detector": ("detector/**",),
    "vehicle": ("sim/**", topics.POSE),
    "mission": ("mission/**", topics.ESTIMATE, topics.PLAN, "team/**"),
}
#: keys outside any one vehicle a role may put: a team's joint estimate (``radseek/team/estimate``)
SHARED_PUTS: dict[str, tuple[str, ...]] = {"mission": (topics.all_keys(topics.TEAM),)}
#: the name a reading process looks for first (any reader's line will do)
READER = "observer"
RECORDER = "recorder"

_NAME = re.compile(r"^[A-Za-z0-9_.-]+(@[A-Za-z0-9_.-]+)?$")


class CredentialsError(ValueError):
    """A credentials file that cannot be used (names the file, and the line when one is at fault)."""


@dataclass(frozen=True)
class User:
    """One line of a credentials file."""

    name: str
    password: str

    @property
    def role(self) -> str | None:
        """``detector``, ``vehicle`` or ``mission``; None for a reader."""
        return parse_name(self.name)[0]

    @property
    def vehicle(self) -> str | None:
        return parse_name(self.name)[1]


def parse_name(name: str) -> tuple[str | None, str | None]:
    """(role, vehicle) of a user name; (None, None) for a reader. ValueError says what is wrong."""
    if not _NAME.match(name):
        raise ValueError(f"user name {name!r} must be ROLE@VEHICLE or a reader's name (letters, digits, '_.-')")
    if "@" not in name:
        return None, None
    who, vehicle = name.split("@")
    role = who.split(".", 1)[0]
    if role not in PUTS:
        raise ValueError(f"user name {name!r}: role {role!r} is not one of {', '.join(PUTS)}")
    return role, vehicle


def user_name(role: str | None, vehicle: str | None = None) -> str:
    """The name a process of ``role`` on ``vehicle`` looks for first (``detector@uav0``; ``observer``)."""
    return READER if role is None else f"{role}@{vehicle}"


def put_keys(user: User) -> list[str]:
    """The key expressions ``user`` may put (none for a reader)."""
    role, vehicle = parse_name(user.name)
    if role is None:
        return []
    return [topics.key(t, vehicle) for t in PUTS[role]] + list(SHARED_PUTS.get(role, ()))


def read_credentials(path: str | Path) -> list[User]:
    """Every user of a credentials file, checked as zenoh would read it and for names radseek understands."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise CredentialsError(f"zenoh credentials {path}: cannot read it ({exc.__class__.__name__}: {exc})") from None
    users: list[User] = []
    for n, line in enumerate(text.splitlines(), 1):
        name, sep, password = line.partition(":")
        if not sep or not name or not password:
            raise CredentialsError(f"zenoh credentials {path} line {n}: expected USER:PASSWORD (no blank lines or "
                                   "comments: zenoh reads this file as it is)")
        try:
            parse_name(name)
        except ValueError as exc:
            raise CredentialsError(f"zenoh credentials {path} line {n}: {exc}") from None
        if any(u.name == name for u in users):
            raise CredentialsError(f"zenoh credentials {path} line {n}: user {name!r} is given twice")
        users.append(User(name, password))
    if not users:  # zenoh would take an empty dictionary as "no authentication"
        raise CredentialsError(f"zenoh credentials {path}: no users (an empty file would let anyone in)")
    return users


def find_user(users: list[User], role: str | None, vehicle: str | None = None, prefer: str | None = None,
              source: str | Path = "") -> User:
    """The user a process of ``role`` on ``vehicle`` connects as: the name ``prefer`` (default
    :func:`user_name`), else the first line with the same role and vehicle (a reader: the first reader)."""
    want = prefer or user_name(role, vehicle)
    for u in users:
        if u.name == want:
            return u
    for u in users:
        if (u.role is None) if role is None else (u.role, u.vehicle) == (role, vehicle):
            return u
    line = f"'{want}:PASSWORD'"
    raise CredentialsError(f"zenoh credentials {source}: no user for {role or 'a reader'}"
                           f"{f' of {vehicle}' if role else ''} (add a line {line})")


def access_control(users: list[User]) -> dict:
    """zenoh's ``access_control`` section: everyone may subscribe and be delivered anything, and each user may
    put only its role's keys of its vehicle (anything else is denied and never forwarded)."""
    rules = [
        {"id": "subscribe", "permission": "allow", "flows": ["ingress", "egress"],
         "messages": ["declare_subscriber"], "key_exprs": ["**"]},
        {"id": "deliver", "permission": "allow", "flows": ["egress"], "messages": ["put"], "key_exprs": ["**"]},
    ]
    subjects: list[dict] = [{"id": "everyone"}]
    policies = [{"rules": ["subscribe", "deliver"], "subjects": ["everyone"]}]
    for u in users:
        keys = put_keys(u)
        if not keys:
            continue
        rules.append({"id": f"put:{u.name}", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
                      "key_exprs": keys})
        subjects.append({"id": f"user:{u.name}", "usernames": [u.name]})
        policies.append({"rules": [f"put:{u.name}"], "subjects": [f"user:{u.name}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def credentials_file(environ: dict[str, str] | None = None) -> Path | None:
    """The credentials file :data:`CREDENTIALS_ENV` names, or None (an open network)."""
    value = (os.environ if environ is None else environ).get(CREDENTIALS_ENV, "")
    return Path(value) if value else None
