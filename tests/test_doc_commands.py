"""The documents' command blocks chain when copied in order (issue 40).

The default suite checks that every ``ambdaq`` command line of every document names a command and
options that exist (the one failure a renamed option would otherwise hide until a user copies it);
``-m long`` runs the blocks of README, push.md then iso.md (one session, as the commissioning day
goes), live.md and fleet.md, each command as a process in one working directory."""

import os
import shlex
from pathlib import Path

import click
import pytest
from doc_blocks import DocSession, blocks

from ambdaq.cli.main import cli

ROOT = Path(__file__).resolve().parent.parent
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])


def _ambdaq_lines():
    for path in DOCS:
        for block in blocks(path):
            if block.language != "sh":
                continue
            for command in block.lines:
                for part in command.split(" && "):
                    part = part.strip().rstrip("&").strip()
                    part = part.split(" > ")[0].split(" | ")[0]
                    if part.startswith("ambdaq "):
                        yield pytest.param(part, id=f"{path.name}:{block.line}:{part[:40]}")


@pytest.mark.parametrize("command", list(_ambdaq_lines()))
def test_every_documented_command_names_what_exists(command):
    """The command path resolves and each ``--option`` the line gives is one the command takes."""
    args = shlex.split(command)[1:]
    group: click.Command = cli
    while isinstance(group, click.Group) and args and not args[0].startswith("-"):
        sub = group.get_command(click.Context(group), args[0])
        assert sub is not None, f"{command}: no command {args[0]!r} under {group.name!r}"
        group, args = sub, args[1:]
    known = {opt for p in group.params for opt in (*p.opts, *p.secondary_opts)} | {"--help"}
    given = {a.split("=")[0] for a in args if a.startswith("-") and not _is_number(a)}
    assert given <= known, f"{command}: {sorted(given - known)} not options of {group.name!r}"


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


SESSIONS = {"readme": ["README.md"], "push-then-iso": ["docs/push.md", "docs/iso.md"], "live": ["docs/live.md"],
            "fleet": ["docs/fleet.md"]}


@pytest.mark.long
@pytest.mark.realtime
@pytest.mark.parametrize("session", list(SESSIONS))
def test_each_documents_command_blocks_run_in_order(session, tmp_path):
    """Every command of the documents' blocks, in order, exits 0 (durations shortened:
    tests/doc_blocks.py says how)."""
    env = {k: v for k, v in os.environ.items() if k != "AMBDAQ_UNLOCK_KEY"}
    run = DocSession(tmp_path, {**env, "AMBDAQ_STATE_DIR": str(tmp_path / "state")})
    try:
        for name in SESSIONS[session]:
            run.run_file(ROOT / name)
    finally:
        run.close()
    assert len(run.ran) >= 3, run.ran
    print("\n".join(run.ran))
