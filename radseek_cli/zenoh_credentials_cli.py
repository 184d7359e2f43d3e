"""``radseek zenoh-credentials``: the zenoh users and passwords of a docker compose stack (docker/compose.yaml).

Writes, in a new 0700 folder (default docker/run, which compose mounts from), one random password per user:
``router.credentials`` lists them all (the router admits only those users and builds its ACL from their names,
as under ``radseek run``), ``detector.credentials``, ``vehicle.credentials`` and ``mission.credentials`` hold
one line each, the credential of that service only. The services run as the image's user (uid 10001), so
those four are given to it (``--owner``; changing a file's owner needs root: run this as root, or under
rootless podman as ``podman unshare radseek zenoh-credentials ...``). ``observer.credentials``,
``observer.json5`` and the folder stay yours (under sudo: the user who ran sudo), for ``radseek echo`` /
``radseek topics`` and zenoh tools on the host through the router's published port. Every file is mode 0600;
none is ever overwritten and no password is printed: remove the folder for new ones, and restart the stack.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from launch.zenoh_auth import write_compose_secrets
from radseek import topics

IMAGE_USER = "10001:10001"


def _owner(text: str) -> tuple[int, int] | None:
    """``UID[:GID]`` (GID defaults to UID), or ``-`` for no change."""
    if text == "-":
        return None
    uid, _, gid = text.partition(":")
    try:
        return int(uid), int(gid or uid)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--owner {text!r}: expected UID[:GID] in numbers, or '-'") from None


def _invoker() -> tuple[int, int] | None:
    """Who ran ``sudo radseek ...`` (the host's tools are theirs), or None (whoever runs this)."""
    if os.geteuid() != 0 or not os.environ.get("SUDO_UID", "").isdigit():
        return None
    return int(os.environ["SUDO_UID"]), int(os.environ.get("SUDO_GID", os.environ["SUDO_UID"]))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="radseek zenoh-credentials", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("docker/run"), help="folder to create (default docker/run)")
    p.add_argument("--vehicle-name", default=topics.DEFAULT_VEHICLE,
                   help=f"the vehicle the services fly (default {topics.DEFAULT_VEHICLE})")
    p.add_argument("--endpoint", default="tcp/127.0.0.1:7447",
                   help="the router as the host reaches it, for observer.json5 (default tcp/127.0.0.1:7447)")
    p.add_argument("--owner", type=_owner, default=IMAGE_USER,
                   help=f"UID[:GID] given the services' files (default {IMAGE_USER}, the image's user; "
                        "'-' keeps yours)")
    args = p.parse_args(argv)
    try:
        files = write_compose_secrets(args.out, args.vehicle_name, args.endpoint, args.owner, _invoker())
    except PermissionError as exc:
        hint = " (changing a file's owner needs root: run as root, or 'podman unshare radseek ...' " \
               "for rootless podman; --owner - keeps yours)" if args.owner else ""
        print(f"radseek zenoh-credentials: cannot write {exc.filename}: {exc.strerror}{hint}; nothing was written",
              file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"radseek zenoh-credentials: {exc.strerror and f'{exc.filename}: {exc.strerror}' or exc}",
              file=sys.stderr)
        return 1
    print(f"radseek zenoh-credentials: wrote {', '.join(f.name for f in files)} in {args.out}", file=sys.stderr)
    return 0
