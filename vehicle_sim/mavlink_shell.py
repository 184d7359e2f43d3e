"""The MAVLink shell as PX4 SITL serves it (what QGroundControl's MAVLink Console, PX4's Tools/mavlink_shell.py,
MAVProxy's ``nsh`` module and MAVSDK's Shell plugin talk to), answered from the vehicle's own state.

Transport, as PX4's mavlink module (mavlink_receiver.cpp ``handle_message_serial_control``, mavlink_main.cpp's shell
output): only SERIAL_CONTROL for device SERIAL_CONTROL_DEV_SHELL without the REPLY flag is taken; its ``count``
bytes (at most the 70 of ``data``) go to the shell of the link it came in on, started by the first such message.
A message without the RESPOND flag closes that shell after its bytes (whatever they ran, their output is lost, as on
PX4, where a closed shell's output pipe is gone). Output goes back on the same link as SERIAL_CONTROL, flags REPLY,
device SHELL, 70 bytes at most each.

The shell is PX4 SITL's, the POSIX ``pxh`` (platforms/posix px4_daemon/pxh.cpp ``run_remote_pxh``), not NuttX's
``nsh`` of a flight controller board: every character above 3 (ASCII, pxh's signed ``char``) is echoed and added to
the line, a newline echoes, runs the line and prints the prompt ``pxh> `` (none before the first newline: clients
send one to get it). Words split on whitespace; a ``#`` line is a comment; an unknown command is answered
``Invalid command: NAME`` / ``type 'help' for a list of commands``, and a command that fails adds ``Command 'NAME'
failed, returned N.``. Log lines are PX4's (``INFO  [module] text``).

Commands, with PX4's wording (systemcmds/ver, systemcmds/param, commander ``print_status`` of PX4 1.14, the version
AUTOPILOT_VERSION announces):

- ``help``: the builtin commands (these four).
- ``ver hw|git|bdate|uri|gcc|px4guid|mcu|all|hwcmp|hwtypecmp``: the version of AUTOPILOT_VERSION (PX4 1.14.0
  release; the git hash whose first 8 bytes PX4 puts in its flight_custom_version, little-endian, as MAVSDK and
  QGroundControl read them back), HW arch PX4_SITL as the ULog says.
- ``param show [-a|-c|-q NAME|FILTER*]`` and ``param set NAME VALUE [fail]``, on the vehicle's parameter table with
  the bounds and read-only rule of PARAM_SET (``ParamTable.assign``). Every parameter is used (x); a value changed
  since boot is unsaved (*): the vehicle keeps no parameter file.
- ``commander status`` (armed, navigation mode, failsafe), ``commander arm [-f]``, ``disarm [-f]``, ``takeoff``
  (arm, then take off to MIS_TAKEOFF_ALT: PX4 sends both), ``land``: the vehicle's own MAVLink commands, so they are
  accepted or refused exactly as a COMMAND_LONG is; a refusal is printed (on PX4 its commander logs it to the same
  console).

Everything else PX4 SITL's shell has (``listener``, ``uorb``, ``top``, ``work_queue``, ``dmesg``, ``reboot``, other
commander and param subcommands...) is absent and says so; PX4's own module log lines (its stdout, which the SITL
shell shares) are not echoed into the shell."""

from __future__ import annotations

import logging
import math
import platform
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as M

from vehicle_sim.commands import FORCE_MAGIC, Answer
from vehicle_sim.navigator import Mode
from vehicle_sim.params import INT32, Param, ParamRefused, ParamTable
from vehicle_sim.telemetry import FLIGHT_SW_VERSION, GIT_HASH, UID

log = logging.getLogger(__name__)

DATA_LEN = 70  # SERIAL_CONTROL's data field
PROMPT = "pxh> "
MAX_LINE = 1024  # characters kept of one input line (pxh has no bound; a hostile client must not grow it forever)
HW_ARCH = "PX4_SITL"
#: PX4 1.14's navigation state names (commander, ModeUtil)
NAV_STATE_NAMES = {Mode.POSCTL: "Position", Mode.ALTCTL: "Altitude", Mode.MISSION: "Mission", Mode.HOLD: "Hold",
                   Mode.RTL: "RTL", Mode.OFFBOARD: "Offboard", Mode.TAKEOFF: "Takeoff", Mode.LAND: "Land",
                   Mode.FOLLOW: "Follow Target", Mode.ORBIT: "Orbit"}


@dataclass(frozen=True)
class ShellStatus:
    """What ``commander status`` tells."""

    armed: bool
    mode: Mode
    failsafe: bool


def px4_log(level: str, module: str, text: str) -> str:
    """One PX4 log line as PX4's console prints it (px4_log.cpp, no colour: not a terminal)."""
    return f"{level:<5} [{module}] {text}\n"


class Pxh:
    """The command interpreter: ``run(line)`` returns what the line prints."""

    def __init__(self, params: ParamTable, status: Callable[[], ShellStatus],
                 command: Callable[[int, tuple[float, ...]], Answer]):
        self.params = params
        self.status = status
        self.command = command  # a MAV_CMD with params 1-4, answered as the vehicle answers a COMMAND_LONG
        self.apps: dict[str, Callable[[list[str]], tuple[str, int]]] = {
            "commander": self._commander, "param": self._param, "ver": self._ver}

    def run(self, line: str) -> str:
        words = line.split()
        if not words:
            return ""
        name = words[0]
        if name in self.apps:
            out, ret = self.apps[name](words)
            return out + (f"Command '{name}' failed, returned {ret}.\n" if ret else "")
        if name == "help":
            return "Builtin Commands:\n" + "".join(f"  {a}\n" for a in sorted(self.apps))
        if name.startswith("#"):
            return ""
        return f"Invalid command: {name}\ntype 'help' for a list of commands\n"

    # -- ver (systemcmds/ver/ver.cpp) ------------------------------------------------------------
    def _ver(self, argv: list[str]) -> tuple[str, int]:
        if len(argv) < 2:
            return px4_log("INFO", "ver", "Error, not enough parameters.\n") + _usage("ver", VER_USAGE), 1
        what, rest = argv[1], argv[2:]
        if what in ("hwcmp", "hwtypecmp"):
            if not rest:
                example = "ver hwcmp PX4_FMU_V2" if what == "hwcmp" else "ver hwtypecmp {V2|V2M|V30|V31}"
                return px4_log("ERROR", "ver", f"Not enough arguments, try '{example}'"), 1
            return "", 0 if what == "hwcmp" and HW_ARCH in rest else 1  # SITL has no hardware type
        lines = [text for key, text in self._versions() if what in ("all", key)]
        if not lines:
            return px4_log("ERROR", "ver", "unknown command"), 1
        return "".join(px4_log("INFO", "ver", t) for t in lines), 0

    @staticmethod
    def _versions() -> list[tuple[str, str]]:
        """(subcommand, line) in ``ver all``'s order."""
        v = FLIGHT_SW_VERSION
        major, minor, patch, kind = v >> 24 & 0xFF, v >> 16 & 0xFF, v >> 8 & 0xFF, v & 0xFF
        release = f"Release {major}.{minor}.{patch}" if kind == 255 else f"{major}.{minor}.{patch} {kind:x}"
        return [("hw", f"HW arch: {HW_ARCH}"), ("git", f"PX4 git-hash: {GIT_HASH[::-1].hex()}"),
                ("git", f"PX4 version: {release} ({v})"), ("git", "Vendor version: 0.0.0 0 (0)"),
                ("git", f"OS: {platform.system()}"), ("git", "OS version: 0.0.0 0 (0)"),
                ("bdate", "Build datetime: n/a (radseek's simulated vehicle)"), ("uri", "Build uri: localhost"),
                ("all", "Build variant: default"),
                ("gcc", f"Toolchain: {platform.python_implementation()}, {platform.python_version()}"),
                ("px4guid", f"PX4GUID: {UID:016x}"), ("mcu", "UNKNOWN MCU")]

    # -- param (systemcmds/param/param.cpp) ------------------------------------------------------
    def _param(self, argv: list[str]) -> tuple[str, int]:
        sub, args = (argv[1], argv[2:]) if len(argv) > 1 else ("", [])
        if sub == "show":
            if args[:1] == ["-q"]:
                p = self.params.find(args[1]) if len(args) > 1 else None
                return ("", 1) if p is None else (_value(p) + "\n", 0)
            if args[:1] == ["-a"]:
                shown = self._show(None, only_changed=False)
                n = len(self.params)
                return shown + f"\n {n} parameters total, {n} used.\n", 0
            only_changed = args[:1] == ["-c"]
            pattern = (args[1:] if only_changed else args)[:1]
            out = self._show(pattern[0] if pattern else None, only_changed)
            return out + f"\n {len(self.params)}/{len(self.params)} parameters used.\n", 0
        if sub == "set":
            if len(args) < 2:
                name = args[0] if args else "PARAM_NAME"
                return px4_log("ERROR", "param", f"not enough arguments.\nTry 'param set {name} 3 [fail]'"), 1
            return self._set(args[0], args[1], fail=args[2:3] == ["fail"])
        return _usage("param", PARAM_USAGE), 1

    def _show(self, pattern: str | None, only_changed: bool) -> str:
        if pattern is not None and "*" in pattern[:-1]:
            return px4_log("WARN", "param", "* symbol only allowed at end of search string")
        out = ["Symbols: x = used, + = saved, * = unsaved\n"]
        for i, p in enumerate(self.params.params):
            if only_changed and p.value == p.default or not _matches(pattern, p.name):
                continue
            out.append(f"x {_saved(p)} {p.name} [{i},{i}] : {_value(p)}\n")
        return "".join(out)

    def _set(self, name: str, text: str, fail: bool) -> tuple[str, int]:
        p = self.params.find(name)
        if p is None:  # PX4: not found fails only with "fail" (so that a boot script goes on)
            return px4_log("ERROR", "param", f"Parameter {name} not found."), 1 if fail else 0
        try:
            v = float(int(text, 10)) if p.ptype == INT32 else float(text)
        except ValueError:
            kind = "an integer" if p.ptype == INT32 else "a number"
            return px4_log("ERROR", "param", f"Parameter {name}: '{text}' is not {kind}."), 1
        if v == p.value:
            return "", 0
        before, state = _value(p), _saved(p)
        try:
            self.params.assign(p, v)
        except ParamRefused as exc:
            if exc.error == M.MAV_PARAM_ERROR_READ_ONLY:
                return px4_log("ERROR", "param", f"Parameter {name} is read-only."), 1
            return px4_log("ERROR", "param", f"Parameter {exc}."), 1
        return f"{state} {name}: curr: {before} -> new: {_value(p)}\n", 0

    # -- commander (modules/commander) -----------------------------------------------------------
    def _commander(self, argv: list[str]) -> tuple[str, int]:
        sub = argv[1] if len(argv) > 1 else ""
        force = FORCE_MAGIC if argv[2:3] == ["-f"] else 0.0
        if sub == "status":
            s = self.status()
            return "".join(px4_log("INFO", "commander", t) for t in (
                "Armed" if s.armed else "Disarmed", f"navigation mode: {NAV_STATE_NAMES[s.mode]}",
                f"in failsafe: {'yes' if s.failsafe else 'no'}")), 0
        sequence = {"arm": [(M.MAV_CMD_COMPONENT_ARM_DISARM, (1.0, force))],
                    "disarm": [(M.MAV_CMD_COMPONENT_ARM_DISARM, (0.0, force))],
                    "takeoff": [(M.MAV_CMD_COMPONENT_ARM_DISARM, (1.0, 0.0)), (M.MAV_CMD_NAV_TAKEOFF, ())],
                    "land": [(M.MAV_CMD_NAV_LAND, ())]}.get(sub)
        if sequence is None:
            why = "unknown command" if not sub else f"{sub}: not in radseek's vehicle shell (send the MAVLink command)"
            return px4_log("WARN", "commander", why) + _usage("commander", COMMANDER_USAGE), 1
        for cmd, params in sequence:
            ans = self.command(cmd, (*params, *(math.nan,) * (4 - len(params))))
            if ans.result != M.MAV_RESULT_ACCEPTED:
                result = M.enums["MAV_RESULT"][ans.result].name.removeprefix("MAV_RESULT_")
                reason = f": {ans.reason}" if ans.reason else ""
                return px4_log("WARN", "commander", f"{sub}: {result}{reason}"), 0  # PX4's commander returns 0 too
        return "", 0


VER_USAGE = [("hw", "Hardware architecture"), ("mcu", "MCU info"), ("git", "git version information"),
             ("bdate", "Build date and time"), ("gcc", "Compiler info"), ("px4guid", "PX4 GUID"),
             ("uri", "Build URI"), ("all", "Print all versions"),
             ("hwcmp", "Compare hardware version (returns 0 on match)"),
             ("hwtypecmp", "Compare hardware type (returns 0 on match)")]
PARAM_USAGE = [("show", "Show parameter values"), ("  [-a]", "Show all parameters (not just used)"),
               ("  [-c]", "Show only changed params (unused too)"),
               ("  [-q]", "quiet mode, print only param value (name needs to be exact)"),
               ("  [<filter>]", "Filter by param name (wildcard at end allowed, eg. sys_*)"),
               ("set", "Set parameter to a value"), ("  <param_name> <value>", "Parameter name and value to set"),
               ("  [fail]", "If provided, let the command fail if param is not found")]
COMMANDER_USAGE = [("status", "Print status"), ("arm", "Arm"), ("  [-f]", "Force arming (do not run preflight checks)"),
                   ("disarm", "Disarm"), ("  [-f]", "Force disarming (disarm in air)"),
                   ("takeoff", "Takeoff"), ("land", "Land")]


def _usage(name: str, commands: list[tuple[str, str]]) -> str:
    """A module's usage as PX4 prints it (the subcommands radseek's shell has)."""
    return (f"Usage: {name} <command> [arguments...]\n Commands:\n"
            + "".join(f"   {c:<13} {d}\n" for c, d in commands) + "\n")


def _matches(pattern: str | None, name: str) -> bool:
    """PX4's filter: case-insensitive, a ``*`` at the end only."""
    if pattern is None:
        return True
    pattern = pattern.upper()
    return name.startswith(pattern[:-1]) if pattern.endswith("*") else name == pattern


def _value(p: Param) -> str:
    return str(int(p.value)) if p.ptype == INT32 else f"{p.value:4.4f}"


def _saved(p: Param) -> str:
    return " " if p.value == p.default else "*"


class MavlinkShell:
    """SERIAL_CONTROL in, SERIAL_CONTROL out: one shell (its partial input line) per link."""

    def __init__(self, pxh: Pxh):
        self.pxh = pxh
        self._lines: dict[str, str] = {}  # link -> the line typed so far, for each open shell

    def handle(self, msg, link: str) -> list:
        """The replies to one SERIAL_CONTROL that came in on ``link``."""
        if msg.device != M.SERIAL_CONTROL_DEV_SHELL or msg.flags & M.SERIAL_CONTROL_FLAG_REPLY:
            return []
        count = int(msg.count)
        if count > DATA_LEN:
            log.info("SERIAL_CONTROL: count %d above the %d bytes of data: ignored", count, DATA_LEN)
            count = 0
        line, out = self._lines.get(link, ""), []
        for b in bytes(msg.data)[:count]:
            if b == 10:
                out += ["\n", self.pxh.run(line), PROMPT]
                line = ""
            elif 3 < b < 128:
                out.append(chr(b))
                line = (line + chr(b))[:MAX_LINE]
        if not msg.flags & M.SERIAL_CONTROL_FLAG_RESPOND:
            self._lines.pop(link, None)  # the client is done with the shell
            return []
        self._lines[link] = line
        return replies("".join(out).encode())


def replies(data: bytes) -> list:
    """``data`` as SERIAL_CONTROL replies of at most 70 bytes each."""
    out = []
    for i in range(0, len(data), DATA_LEN):
        chunk = data[i:i + DATA_LEN]
        out.append(M.MAVLink_serial_control_message(M.SERIAL_CONTROL_DEV_SHELL, M.SERIAL_CONTROL_FLAG_REPLY, 0, 0,
                                                    len(chunk), list(chunk.ljust(DATA_LEN, b"\x00"))))
    return out
