"""The command blocks of the documentation, read and run as a user copies them into a terminal.

A fenced block marked ``sh`` is commands, in the order a user types them; a bare fence is what
a command printed, and is not run; a ``python`` block is run as a script. ``DocSession`` runs a
document's blocks in one working directory, as one terminal would, with what a test must change
to run on this machine and in the suite's time (each change named in :meth:`DocSession.adapt`):

- the setup a user does once (``python3 -m venv``, ``pip install``, the test command itself) is
  the test's own environment, and skipped;
- ``ambdaq sim serve`` runs in the background (a terminal of its own in the docs) and the
  pseudo-terminal and XCP address it prints replace the ones the document shows; it is stopped
  when another starts or no later command of the document reaches a server;
- durations are capped at ``MAX_DURATION_S`` and ``iso stability`` excites each axis for
  ``STABILITY_S`` (the documents' own figures come from the full durations).
"""

from __future__ import annotations

import os
import queue
import re
import shlex
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

SERVED = re.compile(r"serial:///dev/pts/|xcp\+tcp://127\.0\.0\.1|can://slcan")  # what reaches a server
MAX_DURATION_S = 3.0
STABILITY_S = 1.5
SETUP = (re.compile(r"^python3? -m venv\b"), re.compile(r"^\. \.venv/bin/activate$"), re.compile(r"^(uv )?pip install\b"),
         re.compile(r"^python -m pytest\b"))


@dataclass(frozen=True)
class Block:
    """One fenced block: its language (``sh`` or ``python``), first line number and lines."""

    language: str
    line: int
    lines: list[str]


def blocks(path: Path) -> list[Block]:
    """The ``sh`` and ``python`` blocks of a Markdown file, in order; a ``sh`` line continued with
    a backslash is joined to the next, and comments are dropped."""
    out, current, lang, start = [], None, "", 0
    for n, line in enumerate(path.read_text().splitlines(), 1):
        fence = re.match(r"^```(\w*)\s*$", line)
        if fence and current is None:
            current, lang, start = [], fence.group(1), n
        elif fence:
            if lang in ("sh", "python"):
                out.append(Block(lang, start, _joined(current) if lang == "sh" else current))
            current = None
        elif current is not None:
            current.append(line)
    return out


def _joined(lines: list[str]) -> list[str]:
    commands, pending = [], ""
    for line in lines:
        text = re.sub(r"(^|\s)#.*$", "", line).rstrip()  # a comment (no document quotes a '#')
        if text.endswith("\\"):
            pending += text[:-1].rstrip() + " "
            continue
        text = (pending + text.strip()).strip()
        pending = ""
        if text:
            commands.append(text)
    return commands


@dataclass
class DocSession:
    """One terminal's worth of state: a working directory, the environment, the background
    servers and what they printed."""

    cwd: Path
    env: dict[str, str]
    servers: list[subprocess.Popen] = field(default_factory=list)
    printed: dict[str, str] = field(default_factory=dict)  # "controller" -> /dev/pts/3, "xcp" -> URL
    ran: list[str] = field(default_factory=list)

    def run_file(self, path: Path) -> None:
        """Every command of ``path``'s blocks in order. A server runs while later commands of the
        document still reach one (a terminal of its own, closed once its work is done, as a user
        would): the pages' servers would otherwise simulate their rigs beside every later command."""
        steps: list[tuple[str, str]] = []
        for block in blocks(path):
            if block.language == "python":
                steps.append(("python", "\n".join(block.lines)))
                continue
            steps += [(f"{path.name}:{block.line}", part.strip()) for command in block.lines
                      for part in command.split(" && ") if not any(p.match(part.strip()) for p in SETUP)]
        for i, (where, command) in enumerate(steps):
            if where == "python":
                self._run([sys.executable, "-c", command], f"{path.name} python")
                continue
            if " sim serve" in command:
                self.close()  # a new server: the addresses the page shows are now its
            self.shell(command, where)
            if not any(SERVED.search(later) for w, later in steps[i + 1 :] if w != "python"):
                self.close()

    def shell(self, command: str, where: str) -> None:
        """One command line: ``export`` sets the environment, ``sim serve`` starts a server, the
        rest runs in bash and must exit 0."""
        if command.startswith("export "):
            name, _, value = command[len("export "):].partition("=")
            self.env[name] = value
            return
        command = self.adapt(command)
        if " sim serve" in command:
            self._serve(command.rstrip("&").strip(), where)
            return
        self._run(["bash", "-c", command], f"{where}: {command}")

    def adapt(self, command: str) -> str:
        """The document's command as it must run here (see the module's docstring)."""
        if "controller" in self.printed:
            command = re.sub(r"serial:///dev/pts/\w+", f"serial://{self.printed['controller']}", command)
        if "xcp" in self.printed:
            command = re.sub(r"xcp\+tcp://127\.0\.0\.1:\d+", self.printed["xcp"], command)
        command = re.sub(r"--xcp tcp:\d+", "--xcp tcp:0", command)
        command = re.sub(r"--duration (\d+(?:\.\d+)?)",
                         lambda m: f"--duration {min(float(m.group(1)), MAX_DURATION_S):g}", command)
        if command.startswith("ambdaq iso stability") and "--duration" not in command:
            command += f" --duration {STABILITY_S:g}"
        return command

    def _serve(self, command: str, where: str) -> None:
        args = shlex.split(command)
        proc = subprocess.Popen([sys.executable, "-m", *args], cwd=self.cwd, env=self.env, stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True)
        self.servers.append(proc)
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
        wanted = {"controller"} | ({"xcp"} if "--xcp" in args else set()) | ({"keyphasor"} if "--can" in args else set())
        seen: dict[str, str] = {}
        while not wanted <= seen.keys():
            try:
                name, _, value = lines.get(timeout=60).strip().partition(" ")
            except queue.Empty:
                raise AssertionError(f"{where}: {command} printed {seen} in 60 s, not {sorted(wanted)}") from None
            seen[name] = value
        self.printed.update(seen)
        self.ran.append(f"{where}: {command} &")

    def _run(self, argv: list[str], what: str) -> None:
        env = {**self.env, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{self.env.get('PATH', '')}"}
        r = subprocess.run(argv, cwd=self.cwd, env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, f"{what}\nexit {r.returncode}\n{r.stdout[-1500:]}\n{r.stderr[-1500:]}"
        self.ran.append(what)

    def close(self) -> None:
        """Stop every server started so far."""
        for proc in self.servers:
            proc.terminate()
        for proc in self.servers:
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
        self.servers.clear()
