"""The README is true: its commands are valid invocations of the built binary, the ones
marked runnable run, and every Python block runs as written.

Conventions (README.md):
- the file opens with exactly two commands, `cargo run --release -- fit -o out/fit` and
  `./test.sh` (an indented block after the title);
- every ```sh / ```bash / ```console block is parsed; each line that invokes Umbra
  (`umbra ...`, `target/release/umbra ...` or `cargo run --release -- ...`) must name a
  real subcommand (`<bin> SUB --help` succeeds) and every flag it uses (`--long`, `-x`)
  must appear in that subcommand's help;
- a block preceded by the line `<!-- test: run -->` is runnable: all its lines are Umbra
  commands on the built-in scene or files under `scenes/`, writing under `out/`; they are
  run in order in a fresh temporary folder (with `scenes` linked to the repository's),
  each with a short timeout, and must exit 0;
- every ```python block runs: the `## Python` example (at most 12 lines, five falling
  loss lines), the `umbra.torch` example (skipped without torch), and any other block.

The binary is UMBRA_BIN (default target/release/umbra); a missing binary fails.
"""
from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
from functools import lru_cache
from pathlib import Path
from typing import List, Tuple

import pytest

from conftest import REPO, require_umbra

README = REPO / "README.md"
RUN_MARK = "<!-- test: run -->"
FENCE = re.compile(r"(?P<mark><!-- test: run -->[ \t]*\n)?```(?P<lang>[A-Za-z]*)[^\n]*\n(?P<body>.*?)^```",
                   re.S | re.M)
SHELL_LANGS = {"sh", "bash", "console", "shell"}
RUN_TIMEOUT = 180  # seconds per runnable command


def readme() -> str:
    return README.read_text()


def blocks() -> List[Tuple[str, bool, str]]:
    """(language, runnable, body) of every fenced block, in order."""
    return [(m.group("lang"), bool(m.group("mark")), m.group("body")) for m in FENCE.finditer(readme())]


def command_lines(body: str) -> List[str]:
    """The logical command lines of a shell block: `$ ` prompts dropped, backslash
    continuations joined, comments and blank lines removed."""
    out, cur = [], ""
    for raw in body.splitlines():
        line = raw.rstrip()
        if line.startswith("$ "):
            line = line[2:]
        if line.endswith("\\"):
            cur += line[:-1] + " "
            continue
        line = cur + line
        cur = ""
        line = re.sub(r"(^|\s)#.*$", "", line).strip()
        if line:
            out.append(line)
    return out


def umbra_args(line: str):
    """The arguments after the program if `line` invokes Umbra, else None."""
    for prefix in ("umbra ", "target/release/umbra ", "./target/release/umbra ",
                   "cargo run --release -- "):
        if line.startswith(prefix):
            return shlex.split(line[len(prefix):])
    return None


def shell_commands() -> List[Tuple[bool, List[str]]]:
    """(runnable, args) of every Umbra command line in the README's shell blocks, plus
    the two opening commands."""
    cmds = [(False, a) for a in (umbra_args(l) for l in opening_commands()) if a is not None]
    for lang, runnable, body in blocks():
        if lang in SHELL_LANGS:
            for line in command_lines(body):
                args = umbra_args(line)
                if args is not None:
                    cmds.append((runnable, args))
    return cmds


def opening_commands() -> List[str]:
    lines = readme().splitlines()
    assert lines[0].startswith("# "), "README should start with its title"
    rest = [l for l in lines[1:6] if l.strip()]
    return [l.strip() for l in rest[:2]]


@lru_cache(maxsize=None)
def help_text(umbra_bin: str, sub: str) -> str:
    r = subprocess.run([umbra_bin, sub, "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, f"`umbra {sub}` is not a subcommand of {umbra_bin}:\n{r.stderr}"
    return r.stdout


def flags_of(args: List[str]) -> List[str]:
    out = []
    for a in args:
        if re.fullmatch(r"--[A-Za-z][\w-]*(=.*)?", a):
            out.append(a.split("=", 1)[0])
        elif re.fullmatch(r"-[A-Za-z]", a):
            out.append(a)
        elif re.fullmatch(r"-[A-Za-z].+", a) and not re.fullmatch(r"-[\d.]+(e-?\d+)?", a):
            out.append(a[:2])  # -Dname=value
    return out


# --- the two opening commands ------------------------------------------------------------

def test_readme_opens_with_the_two_commands():
    assert opening_commands() == ["cargo run --release -- fit -o out/fit", "./test.sh"]


# --- every Umbra command line is a valid invocation ----------------------------------------

def test_readme_commands_use_real_subcommands_and_flags(umbra_bin):
    require_umbra(umbra_bin)
    cmds = shell_commands()
    assert len(cmds) >= 5, f"too few Umbra commands found in the README: {cmds}"
    bad = []
    for _, args in cmds:
        assert args, "an `umbra` line without a subcommand"
        sub = args[0]
        text = help_text(umbra_bin, sub)
        for flag in flags_of(args[1:]):
            if flag in ("-h", "--help"):
                continue
            if not re.search(r"(?<![\w-])" + re.escape(flag) + r"(?![\w-])", text):
                bad.append(f"umbra {' '.join(args)}: {flag} is not in `umbra {sub} --help`")
    assert not bad, "\n".join(bad)


def test_readme_has_runnable_blocks_that_follow_the_convention():
    runnable = [args for r, args in shell_commands() if r]
    assert len(runnable) >= 3, "the README should mark some command blocks runnable"
    for lang, is_run, body in blocks():
        if not is_run:
            continue
        assert lang in SHELL_LANGS, f"{RUN_MARK} before a {lang!r} block"
        for line in command_lines(body):
            args = umbra_args(line)
            assert args is not None, f"a runnable block runs Umbra commands only: {line!r}"
            for a in args[1:]:
                if "/" in a or re.search(r"\.(npy|npz|hdf5|h5|exr|xml|toml|obj|mat|png)$", a):
                    assert a.startswith(("out/", "scenes/")), \
                        f"runnable commands read scenes/ and write under out/: {line!r}"


def test_readme_runnable_commands_run(umbra_bin, tmp_path):
    require_umbra(umbra_bin)
    (tmp_path / "scenes").symlink_to(REPO / "scenes", target_is_directory=True)
    ran = 0
    for lang, is_run, body in blocks():
        if not (is_run and lang in SHELL_LANGS):
            continue
        for line in command_lines(body):
            args = umbra_args(line)
            try:
                r = subprocess.run([umbra_bin, *args], cwd=tmp_path, capture_output=True,
                                   text=True, timeout=RUN_TIMEOUT,
                                   env={**os.environ, "NO_COLOR": "1"})
            except subprocess.TimeoutExpired:
                pytest.fail(f"README command took over {RUN_TIMEOUT} s: umbra {' '.join(args)}")
            assert r.returncode == 0, (
                f"README command failed (exit {r.returncode}): umbra {' '.join(args)}\n"
                f"{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
            ran += 1
    assert ran >= 3
    assert (tmp_path / "out").is_dir()


# --- links and tone ---------------------------------------------------------------------

def test_readme_links_exist():
    missing = []
    for target in re.findall(r"\]\(([^)\s]+)\)", readme()):
        if re.match(r"[a-z]+://|#|mailto:", target):
            continue
        if not (REPO / target.split("#", 1)[0]).exists():
            missing.append(target)
    assert not missing, f"README links to missing files: {missing}"


def test_readme_is_short_and_not_a_lab_notebook():
    text = readme()
    assert len(text.splitlines()) <= 250, "the README should stay about 200 lines"
    assert not re.search(r"\b(issue|session)s? \d+", text, re.I), "no issue or session numbers"
    assert "DESIGN §" not in text


# --- Python blocks ----------------------------------------------------------------------

def python_blocks() -> List[str]:
    return [body for lang, _, body in blocks() if lang == "python"]


def run_block(code: str, cwd: Path) -> str:
    out = io.StringIO()
    old = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out):
            exec(compile(code, "README.md", "exec"), {"__name__": "__readme__"})
    finally:
        os.chdir(old)
    return out.getvalue()


def losses_of(stdout: str) -> List[float]:
    return [float(line.split()[1]) for line in stdout.splitlines() if line.strip()]


def test_readme_python_example_runs():
    text = readme()
    block = re.search(r"## Python\n.*?```python\n(.*?)```", text, re.S)
    assert block, "README has no Python example"
    code = block.group(1)
    assert len(code.strip().splitlines()) <= 12, "the example should stay about ten lines"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, "README.md", "exec"), {})
    losses = [float(line.split()[1]) for line in out.getvalue().splitlines()]
    assert len(losses) == 5 and losses[-1] < 0.8 * losses[0], losses


def torch_block() -> str:
    found = [b for b in python_blocks() if "umbra.torch" in b]
    assert len(found) == 1, "README should have one umbra.torch example"
    return found[0]


def test_readme_torch_example_runs(tmp_path):
    code = torch_block()
    assert len(code.strip().splitlines()) <= 12, "the torch example should stay short"
    pytest.importorskip("torch", reason="PyTorch is not installed (UMBRA_SKIP_TORCH=1?)")
    losses = losses_of(run_block(code, tmp_path))
    assert len(losses) == 5 and losses[-1] < 0.8 * losses[0], losses


def test_every_other_python_block_runs(tmp_path):
    """Blocks other than the two examples above are run too (in a temporary folder), so
    no Python snippet in the README goes untested."""
    main = re.search(r"## Python\n.*?```python\n(.*?)```", readme(), re.S).group(1)
    others = [b for b in python_blocks() if b != main and "umbra.torch" not in b]
    for code in others:
        if "torch" in code:
            pytest.importorskip("torch")
        run_block(code, tmp_path)
