"""The Ray a campaign runs on: an embedded loopback cluster that dies with the campaign, or an existing cluster.

:func:`start_ray` with no address starts Ray's local cluster on 127.0.0.1 (Ray's single-node mode), in a temporary
folder of its own, watched by a reaper (``launch.ray_reaper``). With ``address`` it connects to a running cluster,
and a failure says why in one line (:class:`RayConnectError`):

- nothing listens at the address (or nothing answers within ``CONNECT_TIMEOUT_S``): checked with a plain TCP connect
  before Ray is asked, because ``ray.init`` to a dead address was seen to wait more than 3 minutes;
- the cluster refused this client's authentication: Ray 2.59 turned token authentication on for ``ray start``
  (https://docs.ray.io/en/latest/ray-security/token-auth.html), and a client without ``RAY_AUTH_MODE=token`` gets
  only "Failed to connect to Ray cluster": the line names the variables to set (``RAY_AUTH_MODE=token`` and the
  token: ``RAY_AUTH_TOKEN``, a file named by ``RAY_AUTH_TOKEN_PATH``, or ``~/.ray/auth_token``).
"""

from __future__ import annotations

import contextlib
import os
import socket
import sys
import tempfile
from collections.abc import Iterator

from launch.ray_reaper import MARK_ENV, Reaper, start_reaper

__all__ = ["CONNECT_TIMEOUT_S", "LOOPBACK_ENV", "RayConnectError", "check_reachable", "connect_error", "is_loopback",
           "start_ray"]

LOOPBACK_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}  # Ray's single-node mode: every server on 127.0.0.1
CONNECT_TIMEOUT_S = 5.0  # s: a Ray head that does not accept a TCP connection in this long is not there
DEFAULT_PORT = 6379  # Ray's GCS port when an address has none
TOKEN_WHERE = ("the cluster's token in RAY_AUTH_TOKEN, or in a file named by RAY_AUTH_TOKEN_PATH, or in "
               "~/.ray/auth_token (`ray get-auth-token` on the head prints it)")


class RayConnectError(ConnectionError):
    """``--address`` names no reachable Ray cluster, or one that refused this client (one line: what to do)."""


def is_loopback(address: str | None) -> bool:
    if address is None:
        return True
    host = address.removeprefix("ray://").rsplit(":", 1)[0].strip("[]")
    return host in ("localhost", "::1") or host.startswith("127.")


def _host_port(address: str) -> tuple[str, int]:
    rest = address.removeprefix("ray://")
    host, sep, port = rest.rpartition(":")
    if not sep or "]" in port:  # no port, or an IPv6 address without one
        return rest.strip("[]"), DEFAULT_PORT if not address.startswith("ray://") else 10001
    try:
        return host.strip("[]"), int(port)
    except ValueError:
        raise RayConnectError(f"--address {address}: the port {port!r} is not a number (HOST:PORT)") from None


def check_reachable(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Raise :class:`RayConnectError` unless something accepts a TCP connection at ``address`` within ``timeout``."""
    if address in ("auto", "local"):
        return
    host, port = _host_port(address)
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return
    except TimeoutError:
        why = f"nothing answered within {timeout:g} s"
    except OSError as exc:
        why = f"nothing listens there ({exc.strerror or exc})"
    raise RayConnectError(f"no Ray cluster at {address}: {why}; start its head (`ray start --head --port {port}`) or "
                          f"give the head's HOST:PORT in --address")


def _chain_text(exc: BaseException) -> str:
    parts = []
    while exc is not None and len(parts) < 5:
        parts.append(f"{type(exc).__name__}: {exc}")
        exc = exc.__cause__ or exc.__context__
    return "\n".join(parts)


def connect_error(address: str, exc: BaseException, env: dict[str, str] | None = None) -> RayConnectError:
    """What a failed ``ray.init(address)`` means, as one line: an authentication refusal names the variables."""
    env = os.environ if env is None else env
    text = _chain_text(exc)
    mode = env.get("RAY_AUTH_MODE", "").strip().lower()
    if "InvalidAuthToken" in text or "AuthenticationError" in text or "Unauthenticated" in text:
        if mode != "token":
            return RayConnectError(
                f"the Ray cluster at {address} wants a token (Ray 2.59+ `ray start --head` turns token "
                f"authentication on) and this client sends none: set RAY_AUTH_MODE=token and {TOKEN_WHERE}")
        return RayConnectError(f"the Ray cluster at {address} refused this client's token: give {TOKEN_WHERE}")
    first = next((line for line in text.splitlines() if line.strip()), type(exc).__name__)
    hint = "" if mode == "token" else (f"; if the cluster uses token authentication (the default of Ray 2.59+ "
                                       f"`ray start`), set RAY_AUTH_MODE=token and {TOKEN_WHERE}")
    return RayConnectError(f"cannot join the Ray cluster at {address}: {first[:200]}{hint}")


def start_ray(workers: int | None, address: str | None, quiet: bool = True,
              niceness: int | None = None) -> Reaper | None:
    """Connect to Ray: an embedded local cluster of ``workers`` CPUs (loopback only, no dashboard, its own
    temporary folder; returned: its :class:`~launch.ray_reaper.Reaper`, to close after ``ray.shutdown()``) or the
    cluster at ``address`` (:class:`RayConnectError` if it cannot be joined). ``niceness``: the embedded
    workers' nice level (Ray's default 15 yields the CPU to everything else on a shared machine)."""
    import logging

    if niceness is not None and address is None:
        os.environ["RAY_worker_niceness"] = str(int(niceness))
    if address is not None:
        check_reachable(address)
    if is_loopback(address):
        # Ray's single-node mode (as on macOS/Windows): its node address is 127.0.0.1 and every Ray server
        # (GCS, raylet, object manager, workers) listens there instead of on all interfaces. Read by Ray at
        # import, so set before the first ``import ray``; a remote cluster needs the default.
        if "ray" in sys.modules and os.environ.get("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER") != "0":
            raise RuntimeError("ray was imported before start_ray(): it would listen on every interface")
        os.environ.update(LOOPBACK_ENV)
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    import ray

    level = logging.ERROR if quiet else logging.WARNING
    if address is None:
        tmp = tempfile.mkdtemp(prefix="radseek-ray-", dir="/tmp")  # short: Ray's socket paths must fit 107 chars
        reaper = start_reaper(tmp)  # a kill -9 of this process takes the cluster and the folder with it
        os.environ[MARK_ENV] = reaper.token  # inherited by every process of the cluster, and only by them
        try:
            ray.init(address="local", num_cpus=workers or os.cpu_count(), include_dashboard=False,
                     _node_ip_address="127.0.0.1", _temp_dir=tmp, object_store_memory=100 * 1024**2,
                     log_to_driver=not quiet, logging_level=level, configure_logging=True)
        except BaseException:
            ray.shutdown()
            reaper.close()
            raise
        finally:
            os.environ.pop(MARK_ENV, None)
        return reaper
    with tempfile.TemporaryFile() as log, _stderr_to(log if quiet else None):
        try:  # quiet: Ray's C++ client logs each of its ~20 retries (a refused token: 20 lines) on fd 2
            ray.init(address=address, log_to_driver=not quiet, logging_level=level, configure_logging=True)
            return None
        except (ConnectionError, RuntimeError) as exc:  # Ray's AuthenticationError is a RuntimeError's cause
            error = exc
    raise connect_error(address, error) from None


@contextlib.contextmanager
def _stderr_to(file) -> Iterator[None]:
    """File descriptor 2 (where Ray's C++ code logs) to ``file`` for a while; None: left alone."""
    if file is None:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    os.dup2(file.fileno(), 2)
    try:
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)
