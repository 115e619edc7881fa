"""The README and docs/ against the tool they describe: the two commands the README opens with
(the second is what `.ci/run` runs), every relative link and image resolving, and every `crank`
command and option the command tables name accepted by the CLI (each command's own --help)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from crank.cli import main

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"(?<!\\)\]\(([^)\s]+)\)")
ROW = re.compile(r"^\| `crank ([a-z]+)([^`]*)` \|(.*)$", re.M)
OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def _fenced_blocks(text: str) -> list[str]:
    return re.findall(r"^```bash\n(.*?)\n```$", text, re.M | re.S)


def test_the_readme_opens_with_its_two_commands_and_ci_runs_the_second() -> None:
    readme = (ROOT / "README.md").read_text()
    head = readme.split("\n## ", 1)[0]
    blocks = _fenced_blocks(head)
    assert len(blocks) == 2, f"the README opens with {len(blocks)} commands, not two"
    run, suite = blocks
    assert "\n" not in run and "\n" not in suite
    assert run.startswith("python3 -m venv .venv && ") and run.endswith(".venv/bin/crank run")
    assert suite.startswith("python3 -m venv .venv && ") and "pytest" in suite
    assert "[sweep]" not in run  # the main job needs no extra
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line.strip()]
    assert ci[-1] == suite, "`.ci/run` does not end with the README's test command verbatim"


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_every_relative_link_of_a_page_resolves(page: Path) -> None:
    broken = [
        target
        for target in LINK.findall(page.read_text())
        if not target.startswith(("http://", "https://", "#", "mailto:"))
        and not (page.parent / target.split("#")[0]).exists()
    ]
    assert broken == [], f"{page.name} links to what is not there: {broken}"


def _rows() -> list[tuple[str, str, str]]:
    rows = []
    for page in (ROOT / "README.md", ROOT / "docs" / "commands.md"):
        for command, rest, _ in ROW.findall(page.read_text()):
            options = sorted(set(OPTION.findall(rest)))
            rows.append((page.name, command, " ".join(options)))
    return rows


ROWS = _rows()


def test_the_command_tables_name_every_subcommand() -> None:
    named = {command for _, command, _ in ROWS}
    assert {"run", "generate", "train", "solve", "replay", "heldout", "study", "sweep"} <= named
    assert {"compare", "import", "export", "verify", "recover", "view", "config"} <= named


@pytest.mark.parametrize(
    ("page", "command", "options"), ROWS, ids=[f"{p}:{c}:{o}" for p, c, o in ROWS]
)
def test_a_command_and_the_options_its_row_names_exist(
    page: str,
    command: str,
    options: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setattr(sys, "argv", ["crank", command, "--help"])
    with pytest.raises(SystemExit) as ended:
        main()
    shown = capsys.readouterr().out
    assert ended.value.code == 0, f"{page}: `crank {command} --help` exited {ended.value.code}"
    known = set(OPTION.findall(shown))
    missing = [option for option in options.split() if option not in known]
    assert missing == [], f"{page}: `crank {command}` has no {missing}"
