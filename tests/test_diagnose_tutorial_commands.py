"""The diagnose tutorial's commands: an `--add` run on a flight diagnosed earlier in the tutorial writes into that
run's folder, so it reuses its fits (fits.pkl) instead of refitting everything (issue 35: the tutorial's section 4
wrote to the default folder while section 1 wrote to runs/tutorial/..., and reran the whole search)."""

import shlex
from pathlib import Path

from radseek_cli.diagnose_cli import _parser, default_out

REPO = Path(__file__).resolve().parents[1]


def _diagnose_commands() -> list[tuple[str, Path, list[str]]]:
    """(dataset, output folder, --add effects) of each `$ radseek diagnose` line, in the tutorial's order."""
    out = []
    lines = (REPO / "docs" / "diagnose-tutorial.md").read_text().splitlines()
    for line in lines:
        if line.startswith("$ radseek diagnose "):
            args = _parser().parse_args(shlex.split(line.split("#")[0])[3:])
            out.append((args.dataset, args.out or default_out(Path(args.dataset)), args.add))
    return out


def test_an_add_after_a_first_run_uses_that_runs_folder():
    cmds = _diagnose_commands()
    assert len(cmds) >= 3
    checked = 0
    for k, (dataset, folder, add) in enumerate(cmds):
        earlier = [f for d, f, _ in cmds[:k] if d == dataset]
        if add and earlier:
            assert folder in earlier, f"`--add` on {dataset} writes to {folder}, not to its first run's {earlier[0]}"
            checked += 1
    assert checked >= 1  # the section 4 command
